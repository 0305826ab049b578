local ns = require "needlesim"
return ns.scenario {
    name = "a solver tolerance out of range",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    solver = { tolerance = 2 },
}
