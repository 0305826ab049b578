local ns = require "needlesim"
-- A misspelt dosimetry field.
return ns.scenario {
    name = "a misspelt dosimetry field",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel, fixed_faces = { "zmax" } },
    dosimetry = { prescripton = 145, plan = { { 0, 0, 0 } } },
}
