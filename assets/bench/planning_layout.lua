-- One layout of `needlesim bench --planning` (engine/bench_planning.c; docs/planning.md): a
-- small gel block on a coarse mesh, a target and up to two fixed obstacles (spheres or
-- cylinders across the block) placed by the bench from its seed, and the tissue's stiffness
-- scaled from the model's. `mode` = "closed" steers with act.steer (RRT around the obstacles,
-- replanning every 2 mm); "open" plans once at the entry with ns.plan (the kinematic model, the
-- arc model's curvature) and runs its actions unchanged. Every value comes by --set.
local ns = require "needlesim"
local act = require "needlesim.actions"

local L, W, H = 0.07, 0.03, 0.03 -- block size [m]
local RES = ns.param("resolution", 0.007) -- lattice spacing [m]
local MODE = ns.param("mode", "closed")
local STIFF = ns.param("stiffness", 1.0) -- x the gel's modulus
local SPEED = ns.param("speed", 0.02) -- insertion speed [m/s]
local CLEAR = ns.param("clearance", 1e-3) -- asked of the planners [m]
local target = { ns.param("tx", 0.055), ns.param("ty", W / 2), ns.param("tz", H / 2) }
if MODE ~= "closed" and MODE ~= "open" then
    error("planning_layout: mode must be closed or open")
end

local gel = ns.material {
    name = "gel x" .. STIFF,
    youngs = 20e3 * STIFF,
    poisson = 0.45,
    density = 1040,
    damping = 5,
    friction = 30,
    cut_force = 0.3,
}
local block = ns.shape.box { center = { L / 2, W / 2, H / 2 }, size = { L, W, H } }
local regions = {
    { name = "gel", shape = block, material = gel },
    -- the back face held: the tissue is held even without obstacles
    { name = "holder", shape = ns.shape.box { center = { L - RES / 2, W / 2, H / 2 },
        size = { RES, W, H } }, material = ns.materials.bone, fixed = true },
}
local obstacles, names = {}, {}
for i = 1, ns.param("obstacles", 0) do
    local p = "o" .. i .. "_"
    local kind = ns.param(p .. "kind", "sphere")
    local c = { ns.param(p .. "x", 0.03), ns.param(p .. "y", W / 2), ns.param(p .. "z", H / 2) }
    local r = ns.param(p .. "r", 0.004)
    local shape
    if kind == "sphere" then
        shape = ns.shape.sphere { center = c, radius = r }
    elseif kind == "cyl_y" or kind == "cyl_z" then
        local a, b = { c[1], c[2], c[3] }, { c[1], c[2], c[3] }
        local k = kind == "cyl_y" and 2 or 3
        a[k], b[k] = -W, 2 * W
        shape = ns.shape.intersection(ns.shape.cylinder { a = a, b = b, radius = r }, block)
    else
        error("planning_layout: " .. p .. "kind must be sphere, cyl_y or cyl_z")
    end
    local name = "obstacle " .. i
    regions[#regions + 1] = { name = name, shape = shape, material = ns.materials.bone,
        fixed = true }
    obstacles[#obstacles + 1] = { name = name, region = name }
    names[#names + 1] = name
end

-- Runs a plan's actions as they are: twist, then insert the action's length, the bevel held
-- for (1 - duty) of it and spun whole turns over the rest (depth along the entry: the
-- kinematic plan's lengths are arc lengths; over these gentle bends the two differ by < 1%).
local function follow(actions)
    local depth = 0
    for _, a in ipairs(actions) do
        if math.abs(a.twist) > 1e-3 then
            act.twist { angle = a.twist, rate = math.pi }
        end
        local held = (1 - a.duty) * a.insert
        if held > 1e-6 then
            depth = depth + held
            act.insert { speed = SPEED, depth = depth }
        end
        local spun = a.duty * a.insert
        if spun > 1e-6 then
            depth = depth + spun
            local turns = math.max(1, math.floor(spun / 2e-3 + 0.5)) -- a turn every ~2 mm
            act.insert { speed = SPEED, depth = depth,
                spin = math.min(60, 2 * math.pi * turns * SPEED / spun) }
        end
    end
end

return ns.scenario {
    name = "planning layout",
    tissue = ns.tissue.shapes {
        resolution = RES,
        bounds = { { 0, 0, 0 }, { L, W, H } },
        regions = regions,
    },
    dt = 0.01,
    needle = ns.needle { kind = "flexible", bevel_deg = 30 },
    entry = { point = { 0, W / 2, H / 2 }, direction = { 1, 0, 0 }, bevel_toward = { 0, 1, 0 } },
    targets = { { name = "target", at = target, tolerance = 2e-3 } },
    obstacles = obstacles,
    script = function()
        if MODE == "closed" then
            act.steer { target = "target", avoid = names, clearance = CLEAR, method = "rrt",
                replan_every = 2e-3, speed = SPEED }
        else
            local plan = ns.plan { target = "target", avoid = names, clearance = CLEAR,
                method = "rrt" }
            if plan.ok then
                follow(plan.actions)
            end
        end
    end,
    -- the tip's clearance from the obstacles, every step, for the bench (both modes)
    on_tick = function(sim)
        sim.planner.track { tip = sim.tip, avoid = names, target_index = 1 }
    end,
}
