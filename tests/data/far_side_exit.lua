-- A needle pushed out through the far side (issue 32): a thin gel block held at its sides, the
-- needle pushed 1 cm past its far face, then withdrawn. The report records a `tip_exit` event
-- and the run goes on: the tip outside no longer cuts, friction acts along the part still in
-- the tissue; drawn back, the tip is at the exit again and retracts as usual.
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.005

return ns.scenario {
    name = "far-side exit",
    dt = 0.01,
    tissue = ns.tissue.box {
        size = { 6 * h, 6 * h, 3 * h }, -- 3 x 3 x 1.5 cm
        origin = { -3 * h, -3 * h, 0 },
        resolution = h,
        material = ns.materials.gel,
        fixed_faces = { "xmin", "xmax" },
    },
    needle = ns.needle { kind = "stiff" },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    targets = { { name = "mid", at = { 0, 0, 0.0075 }, tolerance = 2e-3 } },
    script = function()
        act.insert { speed = 0.02, depth = 0.025 }
        act.wait { time = 0.05 }
        act.retract { speed = 0.02 }
    end,
}
