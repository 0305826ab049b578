-- a shape function that yields: the error Lua raises has no position of its own
local ns = require "needlesim"
return ns.scenario { name = "y", tissue = ns.tissue.shapes { resolution = 5e-3,
    bounds = { { -0.02, -0.02, -0.02 }, { 0.02, 0.02, 0.02 } },
    regions = { { name = "gel", shape = function(x, y, z) coroutine.yield() return -1 end, material = ns.materials.gel, fixed = true } } } }
