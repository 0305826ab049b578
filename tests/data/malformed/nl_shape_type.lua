-- a shape's type rewritten with a newline: "unknown shape type '...'" shows it as it is
local ns = require "needlesim"
local s = ns.shape.sphere { center = { 0, 0, 0 }, radius = 0.01 }
s.type = "blob\nsecond line"
return ns.scenario { name = "t", tissue = ns.tissue.shapes { resolution = 0.005,
    regions = { { name = "a", shape = s, material = ns.materials.gel, fixed = true } } } }
