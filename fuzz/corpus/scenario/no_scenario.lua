local ns = require "needlesim"
local tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
    material = ns.materials.gel }
return { name = "not a scenario", tissue = tissue }
