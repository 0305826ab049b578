local ns = require "needlesim"
return ns.scenario {
    name = "an arc curvature for a needle that steers by force",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    needle = ns.needle { kind = "flexible", curvature = 8 },
}
