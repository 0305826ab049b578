-- Tutorial: the smallest complete scenario (docs/scenarios.md walks through it).
--
-- What it teaches: the parts every scenario has. A block of gel (the tissue), a needle, where
-- the needle goes in (entry), a target to reach, and a script that drives the needle: in to
-- the target's depth, then a short wait while the tissue settles. The target moves with the
-- tissue the needle pushes; the report scores where the tip ended against where the target is.
--
--   needlesim run scenarios/tutorial.lua -o out/tutorial
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.005 -- lattice spacing [m]: 5 mm

return ns.scenario {
    name = "tutorial",
    description = "a stiff needle into a gel block, to a target 3 cm deep",
    dt = 0.01, -- time step [s]
    tissue = ns.tissue.box {
        size = { 8 * h, 8 * h, 10 * h }, -- 4 x 4 x 5 cm
        origin = { -4 * h, -4 * h, 0 }, -- the top face is z = 0, the needle goes along +z
        resolution = h,
        material = ns.materials.gel,
        fixed_faces = { "zmax" }, -- the block rests on its far face
    },
    needle = ns.needle { kind = "stiff" }, -- an 18 G steel needle, symmetric tip
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    targets = {
        { name = "target", at = { 0, 0, 0.03 }, tolerance = 2e-3 },
    },
    -- a live session (`needlesim live`, docs/live.md) steps at the cheapest setting measured
    -- on the brachytherapy front within 0.5 mm at the tip (dt 20 ms); `needlesim run` keeps
    -- the dt above
    live = { accuracy = 0.5e-3, front = "brachytherapy" },
    script = function()
        act.insert { speed = 0.02, depth = 0.03 } -- 20 mm/s to 3 cm
        act.wait { time = 0.2 }
    end,
}
