local ns = require "needlesim"
-- A dose grid finer than sim/ns_limits.h's NS_LIMIT_DOSE_SPACING_MIN.
return ns.scenario {
    name = "a dose grid too fine",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel, fixed_faces = { "zmax" } },
    dosimetry = { spacing = 1e-5, plan = { { 0, 0, 0 } } },
}
