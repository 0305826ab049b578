-- A needle withdrawn all the way out and pushed in again (issue 35): into a gel block, drawn
-- back out of it, in again through the same hole, out, its base moved 1 cm sideways, and in at
-- that new point. Each re-insertion is a fresh skin entry where the needle crosses the surface
-- (sim/coupling_reentry.c): the report records two `needle_reentry` events and the tip cuts
-- again both times.
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.005

return ns.scenario {
    name = "re-entry",
    dt = 0.01,
    tissue = ns.tissue.box {
        size = { 8 * h, 8 * h, 6 * h }, -- 4 x 4 x 3 cm
        origin = { -4 * h, -4 * h, 0 },
        resolution = h,
        material = ns.materials.gel,
        fixed_faces = { "zmax" },
    },
    needle = ns.needle { kind = "stiff" },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    script = function()
        act.insert { speed = 0.02, depth = 0.015 }
        act.retract { speed = 0.02 }
        act.insert { speed = 0.02, depth = 0.01 } -- the same hole
        act.retract { speed = 0.02 }
        act.move_base { velocity = { 0.01, 0, 0 }, time = 1.0 }
        act.insert { speed = 0.02, depth = 0.01 } -- a new entry, 1 cm over
        act.wait { time = 0.05 }
    end,
}
