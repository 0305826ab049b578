local ns = require "needlesim"
-- Dosimetry of a region the tissue does not have.
return ns.scenario {
    name = "dosimetry of a missing region",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel, fixed_faces = { "zmax" } },
    entry = { point = { 0, 0, -0.01 }, direction = { 0, 0, 1 } },
    dosimetry = { plan = { { 0, 0, 0 } } },
}
