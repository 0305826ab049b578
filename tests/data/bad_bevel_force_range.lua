local ns = require "needlesim"
-- A bevel force out of range (sim/ns_limits.h: NS_LIMIT_BEVEL_FORCE).
return ns.scenario {
    name = "a bevel force out of range",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel, fixed_faces = { "zmax" } },
    needle = ns.needle { kind = "flexible", bevel_force = 50 },
}
