-- a tissue that takes seconds to mesh (C code the Lua hook never sees), for the signal cases
local ns = require "needlesim"
local act = require "needlesim.actions"
return ns.scenario { name = "slow mesh", tissue = ns.tissue.box { size = { 0.07, 0.07, 0.07 },
    origin = { -0.035, -0.035, 0 }, resolution = 1e-3, material = ns.materials.gel,
    fixed_faces = { "zmax" } },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    script = function() act.wait { time = 0.01 } end }
