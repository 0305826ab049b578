local ns = require "needlesim"
return ns.scenario {
    name = "a camera view that does not exist",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    camera = { views = { "side", "front" } },
}
