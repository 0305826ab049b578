local ns = require "needlesim"
return ns.scenario {
    name = "missing mesh",
    tissue = ns.tissue.file {
        path = "pelvis.msh",
        regions = { [1] = ns.materials.prostate },
    },
}
