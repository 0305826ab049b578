local ns = require "needlesim"
return ns.scenario {
    name = "misspelt box field",
    tissue = ns.tissue.box {
        size = { 0.02, 0.02, 0.02 }, resolutoin = 0.004, material = ns.materials.gel,
    },
}
