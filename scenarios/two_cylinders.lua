-- Two-cylinder steering (the paper's Fig. 8): a block of gel with two rigid cylindrical
-- obstacles across it. A bevel-tip needle inserted along +x from the middle of the x = 0 face
-- meets the first rod almost head on and has to be steered above it, then twisted to bend
-- back down under the second one (later versions add the needle, targets and the script).
--
-- What it teaches:
--   * ns.tissue.shapes: several regions meshed into one conforming mesh;
--   * later regions override earlier ones: the rods are carved out of the block because they
--     come after it in the list;
--   * fixed regions: every node of a rod is held in place (rigid obstacles);
--   * CSG: each rod is a long cylinder intersected with the block, so it ends flush with the
--     block's faces instead of sticking out of it;
--   * bounds: the lattice is anchored at the block's corner, so its faces stay flat.
--
-- The paper's mesh had 3,248 tets and 813 nodes; this one is of the same size
-- (`needlesim check scenarios/two_cylinders.lua`).
local ns = require "needlesim"

local L, W, H = 0.10, 0.06, 0.04 -- block size along x (insertion), y, z [m]
local R = 0.006 -- rod radius [m]

local block = ns.shape.box { center = { L / 2, W / 2, H / 2 }, size = { L, W, H } }

-- A rod across the block along z through (x, y), cut flush with the block.
local function rod(x, y)
    local long = ns.shape.cylinder { a = { x, y, -H }, b = { x, y, 2 * H }, radius = R }
    return ns.shape.intersection(long, block)
end

return ns.scenario {
    name = "two-cylinder steering",
    description = "gel block with two fixed cylindrical obstacles (Chentanez et al. 2009, Fig. 8)",
    tissue = ns.tissue.shapes {
        resolution = 0.01, -- 10 x 6 x 4 lattice cells
        bounds = { { 0, 0, 0 }, { L, W, H } },
        regions = {
            { name = "gel", shape = block, material = ns.materials.gel },
            -- The straight path (y = W/2) runs into the top of the near rod (y 2.0-3.2 cm) ...
            { name = "near rod", shape = rod(0.035, W / 2 - 0.004), material = ns.materials.bone,
                fixed = true },
            -- ... and the far rod (y 3.2-4.4 cm) blocks the way over it, further in.
            { name = "far rod", shape = rod(0.065, W / 2 + 0.008), material = ns.materials.bone,
                fixed = true },
        },
    },
}
