local ns = require "needlesim"
return ns.scenario {
    name = "misspelt scenario field",
    tisue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
}
