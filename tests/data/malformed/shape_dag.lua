-- A shape whose children are shared: 41 tables in Lua, 2^40 leaves once C copies it into a
-- tree (SHAPE_DEPTH_MAX bounds the depth, nothing bounds the total) (issue 32: hung)
local ns = require "needlesim"
local s = ns.shape.sphere { center = { 0, 0, 0 }, radius = 0.01 }
for _ = 1, 40 do s = ns.shape.union(s, s) end
return ns.scenario { name = "dag", tissue = ns.tissue.shapes { resolution = 0.005,
    regions = { { name = "a", shape = s, material = ns.materials.gel, fixed = true } } } }
