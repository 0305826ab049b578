-- The well-formed scenario every malformed case starts from (tests/test_malformed.sh): a
-- tutorial-sized gel block; each case changes one thing after the constructors checked it.
local ns = require "needlesim"
local act = require "needlesim.actions"
local M = {}

function M.scenario(script)
    local h = 0.01
    return ns.scenario {
        name = "malformed",
        dt = 0.01,
        tissue = ns.tissue.box { size = { 4 * h, 4 * h, 4 * h }, origin = { -2 * h, -2 * h, 0 },
            resolution = h, material = ns.materials.gel, fixed_faces = { "zmax" } },
        needle = ns.needle { kind = "stiff" },
        entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
        targets = { { name = "target", at = { 0, 0, 0.02 }, tolerance = 2e-3 } },
        script = script or function() act.insert { speed = 0.02, depth = 0.005 } end,
    }
end

return M
