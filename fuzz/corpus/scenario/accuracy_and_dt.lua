local ns = require "needlesim"
return ns.scenario {
    name = "accuracy with its own dt",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    dt = 0.01,
    accuracy = 1e-3,
}
