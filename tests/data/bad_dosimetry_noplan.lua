local ns = require "needlesim"
-- Dosimetry without a plan or seeds.
return ns.scenario {
    name = "dosimetry without a plan",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel, fixed_faces = { "zmax" } },
    dosimetry = { prescription = 145 },
}
