-- a function shape that is cheap once but called for every lattice vertex: the budget
-- belongs to the whole load, not to one call
local ns = require "needlesim"
local function slow(x, y, z)
    local s = 0
    for i = 1, 20000 do s = s + i end
    return math.max(math.abs(x), math.abs(y), math.abs(z)) - 0.02
end
return ns.scenario { name = "slow", tissue = ns.tissue.shapes { resolution = 2e-3,
    bounds = { { -0.03, -0.03, -0.03 }, { 0.03, 0.03, 0.03 } },
    regions = { { name = "gel", shape = slow, material = ns.materials.gel, fixed = true } } } }
