-- Two-cylinder steering (the paper's Fig. 8): a block of gel with two rigid cylindrical
-- obstacles across it and a goal beyond them. A bevel-tip needle enters the x = 0 face 1 cm
-- off centre (y = 4 cm, beside the near rod), its bevel steering it towards +y: it curves up
-- past the far rod, which a straight needle would hit, and half a turn of the base at 6.5 cm
-- levels it off towards the goal. Each rod entered costs 25 points.
--
-- What it teaches:
--   * ns.tissue.shapes: several regions meshed into one conforming mesh;
--   * later regions override earlier ones: the rods are carved out of the block because they
--     come after it in the list;
--   * fixed regions: every node of a rod is held in place (rigid obstacles);
--   * CSG: each rod is a long cylinder intersected with the block, so it ends flush with the
--     block's faces instead of sticking out of it;
--   * bounds: the lattice is anchored at the block's corner, so its faces stay flat.
--   * obstacles (the rods' regions), entry.bevel_toward, and steering by act.twist;
--   * or (--set steer=true) closed-loop steering around the rods by act.steer.
--
-- The paper's mesh had 3,248 tets and 813 nodes; this one is of the same size
-- (`needlesim check scenarios/two_cylinders.lua`).
local ns = require "needlesim"
local act = require "needlesim.actions"

local L, W, H = 0.10, 0.06, 0.04 -- block size along x (insertion), y, z [m]
local R = 0.006 -- rod radius [m]
-- --set steer=true: closed-loop steering (act.steer, docs/planning.md) instead of the scripted
-- twist: an RRT around both rods, replanned every 2 mm from the tip's pose.
local STEER = ns.param("steer", false)

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
    dt = 0.01,
    -- The needle steers in the x-y plane: seen from above, cut level with it, the rods show as
    -- discs beside its path; the side view beside it.
    camera = { views = { "top", "side" } },
    needle = ns.needle { kind = "flexible", bevel_deg = 30 },
    -- On the lattice line y = 4 cm, z = 2 cm, the bevel steering towards +y at first.
    entry = { point = { 0, 0.04, 0.02 }, direction = { 1, 0, 0 }, bevel_toward = { 0, 1, 0 } },
    targets = { { name = "goal", at = { 0.09, 0.054, 0.02 }, tolerance = 3e-3 } },
    obstacles = {
        { name = "near rod", region = "near rod" },
        { name = "far rod", region = "far rod" },
    },
    script = function()
        if STEER then
            act.steer { target = "goal", avoid = { "near rod", "far rod" }, method = "rrt" }
            return
        end
        -- Up past the far rod, then half a turn to level off towards the goal.
        act.insert { speed = 0.01, depth = 0.065 }
        act.twist { angle = math.pi }
        act.insert { speed = 0.01, depth = 0.09 }
    end,
}
