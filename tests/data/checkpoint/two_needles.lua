-- tests/test_checkpoint.sh: the tutorial's gel block, a needle in and out, then a second needle
-- through a tilted entry (act.next_needle changes the run's entry, which a checkpoint carries).
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.005
local refine = ns.param("tissue.refine", 1) -- a --set for the test to carry

return ns.scenario {
    name = "two needles",
    dt = 0.01,
    tissue = ns.tissue.box {
        size = { 8 * h, 8 * h, 10 * h },
        origin = { -4 * h, -4 * h, 0 },
        resolution = h / refine,
        material = ns.materials.gel,
        fixed_faces = { "zmax" },
    },
    needle = ns.needle { kind = "stiff" },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    targets = {
        { name = "target", at = { 0.004, 0, 0.02 }, tolerance = 2e-3 },
    },
    script = function()
        act.insert { speed = 0.02, depth = 0.012 }
        act.retract { speed = 0.02 }
        act.next_needle { point = { 0.004, 0.004, 0 }, direction = { 0.2, 0, 1 } }
        act.insert { speed = 0.02, depth = 0.02 }
    end,
}
