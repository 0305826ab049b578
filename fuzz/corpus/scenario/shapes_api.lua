-- Exercises every shape constructor, transforms, a function shape and ns.material{base=}:
-- the mesh must build with every region non-empty.
local ns = require "needlesim"
local S = ns.shape

local soft = ns.material { base = ns.materials.gel, name = "soft gel", youngs = 8e3 }
local block = S.box { center = { 0.02, 0.02, 0.02 }, size = { 0.04, 0.04, 0.04 } }
local ring = S.difference(
    S.cylinder { a = { 0.02, 0.02, 0.004 }, b = { 0.02, 0.02, 0.012 }, radius = 0.014 },
    S.cylinder { a = { 0.02, 0.02, 0.0 }, b = { 0.02, 0.02, 0.016 }, radius = 0.007 })
local pill = S.rotate(S.capsule { a = { -0.008, 0, 0 }, b = { 0.008, 0, 0 }, radius = 0.004 },
    "z", math.pi / 4)
pill = S.translate(pill, { 0.02, 0.02, 0.028 })
local egg = S.translate(S.scale(S.ellipsoid { center = { 0, 0, 0 }, radii = { 0.5, 0.3, 0.3 } },
    0.016), { 0.02, 0.02, 0.02 })
local function ball(x, y, z) -- a plain Lua function: signed distance, negative inside
    return math.sqrt((x - 0.032) ^ 2 + (y - 0.032) ^ 2 + (z - 0.032) ^ 2) - 0.005
end

return ns.scenario {
    name = "shapes api",
    tissue = ns.tissue.shapes {
        resolution = 0.003,
        bounds = { { 0, 0, 0 }, { 0.04, 0.04, 0.04 } },
        regions = {
            { name = "block", shape = block, material = ns.materials.fat },
            { name = "egg", shape = S.intersection(egg, block), material = soft },
            { name = "ring", shape = ring, material = ns.materials.muscle },
            { name = "pill", shape = S.union(pill), material = ns.materials.prostate },
            { name = "ball", shape = ball, material = ns.materials.bone, fixed = true },
        },
    },
}
