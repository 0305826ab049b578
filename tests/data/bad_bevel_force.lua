local ns = require "needlesim"
return ns.scenario {
    name = "a bevel force for a needle that steers by the arc model",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    needle = ns.needle { kind = "flexible", steering = "arc", bevel_force = 0.3 },
}
