local ns = require "needlesim"
-- a resolution just under the lattice vertex limit: gigabytes before the first tet
return ns.scenario { name = "fine", tissue = ns.tissue.box { size = { 0.2, 0.2, 0.2 },
    resolution = 6e-4, material = ns.materials.gel, fixed_faces = { "zmax" } } }
