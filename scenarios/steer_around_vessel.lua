-- Steering around a vessel (issue 36): a liver-like block with a blood vessel running across it
-- straight between the entry and a lesion. A straight needle would go through the vessel; a
-- bevel-tip needle steered in closed loop (act.steer, docs/planning.md) bends out past it and
-- back onto the lesion, replanning every couple of millimetres from the tip's pose and the
-- lesion where the tissue has carried it, with an RRT around the vessel.
--
-- What it teaches:
--   * act.steer{target, avoid, clearance, method}: closed-loop steering, the curvature it
--     predicts with estimated from the tip's path (the force steering model's is not known
--     in advance);
--   * report.json's `steering` object: replans, planning time, the least clearance to the
--     vessel, the final error;
--   * a fixed region as a vessel (held in place: stiff against the needle), cut flush with
--     the block like two_cylinders.lua's rods.
--
-- The needle follows the arc steering model (its curvature k_c tan(psi), the one the planner
-- assumes, though act.steer still estimates it from the tip's path); `--set steering=force`
-- runs the force model, whose tip swings with the bevel's side and whose curvature is not
-- known in advance (docs/planning.md gives both runs' figures). `--set method=helix` steers with
-- the plain closed loop, which does not look at the vessel; `--set replan_every=M` (default
-- 2 mm).
local ns = require "needlesim"
local act = require "needlesim.actions"

local L, W, H = 0.10, 0.04, 0.03 -- block size along x (insertion), y, z [m]
local R = 0.003 -- vessel radius [m] (a portal vein branch)
local METHOD = ns.param("method", "rrt")
local EVERY = ns.param("replan_every", 2e-3) -- [m]
local STEERING = ns.param("steering", "arc") -- the needle's steering model (docs/needle.md)
-- --set rollout=true: act.steer measures the curvature by a rollout in the simulator before
-- each replan instead of estimating it from the tip's path (docs/planning.md)
local ROLLOUT = ns.param("rollout", false)

-- Liver-like (an estimate): published liver moduli spread widely with method, rate and
-- preconditioning, from a few kPa (in vivo elastography of healthy human liver, e.g. Sandrin et
-- al. 2003, Ultrasound Med Biol 29:1705) to tens of kPa (ex vivo indentation of animal liver).
-- We take 20 kPa, as the gel's; at 10 kPa this coarse mesh let the tip wander ~0.5 mm from step
-- to step, too much for act.steer's curvature estimate. The rest as the gel's (estimates,
-- scripts/needlesim/materials.lua).
local liver = ns.material {
    name = "liver (estimate)",
    youngs = 20e3,
    poisson = 0.45,
    density = 1060,
    damping = 5,
    friction = 30,
    cut_force = 0.3,
}

local block = ns.shape.box { center = { L / 2, W / 2, H / 2 }, size = { L, W, H } }
-- The vessel runs across the block along z, 2.5 mm off the straight line from the entry to the
-- lesion: a straight needle would cut it.
local VY = W / 2 - 0.0025
local vessel = ns.shape.intersection(
    ns.shape.cylinder { a = { 0.045, VY, -H }, b = { 0.045, VY, 2 * H }, radius = R }, block)

return ns.scenario {
    name = "steering around a vessel",
    description = "liver-like block, a vessel between the entry and a lesion; act.steer around it",
    tissue = ns.tissue.shapes {
        resolution = 0.006, -- fine enough for the 3 mm vessel to have tets of its own
        bounds = { { 0, 0, 0 }, { L, W, H } },
        regions = {
            { name = "liver", shape = block, material = liver },
            { name = "vessel", shape = vessel, material = ns.materials.bone, fixed = true },
        },
    },
    dt = 0.01,
    camera = { views = { "top", "side" } },
    needle = ns.needle { kind = "flexible", bevel_deg = 30, steering = STEERING },
    entry = { point = { 0, W / 2, H / 2 }, direction = { 1, 0, 0 }, bevel_toward = { 0, 1, 0 } },
    targets = { { name = "lesion", at = { 0.09, W / 2, H / 2 }, tolerance = 1e-3 } },
    obstacles = { { name = "vessel", region = "vessel" } },
    script = function()
        act.steer { target = "lesion", avoid = { "vessel" }, clearance = 1e-3, method = METHOD,
            replan_every = EVERY, speed = 0.01, rollout = ROLLOUT }
    end,
}
