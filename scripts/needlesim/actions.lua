-- needlesim.actions: the blocking-style actions a scenario's script is written with.
--
--   local act = require "needlesim.actions"
--   script = function()
--     act.insert{ speed = 0.01, depth = 0.03 }   -- 10 mm/s until 3 cm deep
--     act.twist{ angle = math.pi }               -- turn the base half a turn
--     act.wait{ time = 0.5 }
--     act.retract{ speed = 0.02 }                -- all the way out
--   end
--
-- The script runs in a coroutine. Each action sets the needle's controls (`sim.control`) and
-- yields once per time step until it is done, so a script reads top to bottom like the
-- procedure it describes. `sim` (also passed to `on_tick`) is read-only for scripts except
-- `sim.control`; docs/scenarios.md lists its fields. A bad argument is an error naming the line
-- of the script that called the action.
local act = {}

local sim -- the engine's view of the run, bound before the script starts (act._bind)
local co -- the script's coroutine
local fresh = true -- the needle at the entry has not been pushed in yet (act.needle)
local entry -- the current needle's entry {point, direction}: the scenario's, then next_needle's

local fmt = string.format

local function finite(x)
    return type(x) == "number" and x == x and x ~= math.huge and x ~= -math.huge
end

local function fields(t, name, known)
    if type(t) ~= "table" then
        error(fmt("act.%s: expected a table of fields {%s} (got %s)", name,
            table.concat(known, ", "), type(t)), 3)
    end
    local set = {}
    for _, k in ipairs(known) do
        set[k] = true
    end
    for k in pairs(t) do
        if not set[k] then
            error(fmt("act.%s: unknown field '%s' (known: %s)", name, tostring(k),
                table.concat(known, ", ")), 3)
        end
    end
end

-- "act.NAME", or NAME itself when it has a dot (ns.plan's fields are checked here too).
local function label(name)
    return name:find(".", 1, true) and name or "act." .. name
end

local function number(t, name, k, test, what, default, level)
    level = level or 3
    local v = t[k]
    if v == nil and default ~= nil then
        return default
    end
    if v == nil then
        error(fmt("%s: missing required field '%s' (a number %s)", label(name), k, what), level)
    end
    if not finite(v) or not test(v) then
        error(fmt("%s: %s must be a number %s (got %s)", label(name), k, what, tostring(v)), level)
    end
    return v
end

-- An insertion or retraction whose depth has not moved by 0.01 mm for this long [s] of
-- simulated time is stuck: the action fails instead of waiting for ever.
local STALL_TIME = 2
-- How far outside the entry point a full retraction takes the tip [m].
local CLEAR = 2e-3

local function GT0(x) return x > 0 end
-- Controls are bounded physically (sim.limits, from sim/ns_limits.h; docs/reliability.md).
local function speed_ok(x) return x > 0 and x <= sim.limits.insert_speed end
local function spin_ok(x) return math.abs(x) <= sim.limits.twist_rate end
local function rate_ok(x) return x > 0 and x <= sim.limits.twist_rate end
local function angle_ok(x) return math.abs(x) <= sim.limits.twist_angle end
local function speed_what() return fmt("in (0, %g] [m/s]", sim.limits.insert_speed) end
local function rate_what() return fmt("in (0, %g] [rad/s]", sim.limits.twist_rate) end
local function GE0(x) return x >= 0 end
local function ANY() return true end

local function running()
    if sim == nil or coroutine.running() ~= co then
        error("needlesim.actions: actions run only inside the scenario's script", 3)
    end
end

local function tick()
    coroutine.yield()
end

local function stop()
    sim.control.v_insert = 0
    sim.control.twist_rate = 0
end

-- Watches a depth that should move one way (sign +1 in, -1 out): the returned function, called
-- after each step, fails at the script's line when the depth has not moved by 0.01 mm that way
-- for STALL_TIME of simulated time.
local function stall_watch(message, sign, wanted)
    local best, since = sim.depth, sim.t
    return function()
        if sign * (sim.depth - best) > 1e-5 then
            best, since = sim.depth, sim.t
        elseif sim.t - since > STALL_TIME then
            error(fmt("%s: depth %.1f mm for %g s, %.1f mm wanted", message, 1e3 * sim.depth,
                STALL_TIME, 1e3 * wanted), 3)
        end
    end
end

-- The scenario's target names, sorted and joined ("none" without any), for messages.
local function target_list()
    local names = {}
    for k in pairs(sim.targets) do
        names[#names + 1] = k
    end
    table.sort(names)
    return #names > 0 and table.concat(names, ", ") or "none"
end

-- The depth still to go to `depth`, or to the target named `to` as it is now (the target moves
-- with the tissue): the target's distance ahead of the tip along the tip's direction, what an
-- operator reads off the ultrasound image. Exactly one of the two is given.
local function goal(t, name)
    if (t.depth ~= nil and t.to ~= nil) or (t.depth == nil and t.to == nil and name ~= "retract")
    then
        error(fmt("act.%s: give exactly one of 'depth' (a number [m]) and 'to' (a target's name)",
            name), 3)
    end
    if t.to == nil then
        local depth = t.depth
        if depth == nil then -- act.retract all the way out: no goal
            return nil
        end
        return function() return depth - sim.depth end
    end
    local to = t.to
    if type(to) ~= "string" or sim.targets[to] == nil then
        error(fmt("act.%s: 'to' must name a target of the scenario (got %s; targets: %s)", name,
            tostring(to), target_list()), 3)
    end
    -- A tip direction that reverses from one step to the next (soft tissue can fold the last
    -- rod edge back for a step) is not believed: the last one that did not reverse is used, so
    -- a one-step flip does not end the action early.
    local last
    return function()
        local x, p, d = sim.targets[to], sim.tip, sim.tip_direction
        if last and d[1] * last[1] + d[2] * last[2] + d[3] * last[3] < 0 then
            d = last
        else
            last = { d[1], d[2], d[3] }
        end
        return (x[1] - p[1]) * d[1] + (x[2] - p[2]) * d[2] + (x[3] - p[3]) * d[3]
    end
end

--- act.insert{speed, depth | to, spin}: push the needle in at `speed` [m/s] until its tip is
-- `depth` [m] past the entry point (measured along the entry direction), or until it reaches
-- the target named `to` where that target is now (image guidance: the tissue the needle pushes
-- carries the target deeper), the base turning at `spin` [rad/s] meanwhile (default 0; spinning
-- a bevel needle as it goes in averages its bend away). Returns true, or false when the tip met
-- bone (a fixed region) first: it stops at the bone's surface and the insertion ends there
-- (sim.bone_contact; the report's events say when and where).
function act.insert(t)
    running()
    fields(t, "insert", { "speed", "depth", "to", "spin" })
    local speed = number(t, "insert", "speed", speed_ok, speed_what())
    if t.depth ~= nil then
        number(t, "insert", "depth", GT0, "> 0 [m]")
    end
    local togo = goal(t, "insert")
    local spin = number(t, "insert", "spin", spin_ok,
        fmt("in [-%g, %g] [rad/s]", sim.limits.twist_rate, sim.limits.twist_rate), 0)
    local watch = stall_watch("act.insert: the needle does not advance", 1, sim.depth + togo())
    fresh = false
    -- A tip that meets bone (a fixed region) stops there: the insertion ends early and the
    -- action returns false (sim.bone_contact; the report's events say when and where).
    while togo() > 0 do
        if sim.bone_contact then
            stop()
            return false
        end
        sim.control.v_insert = speed
        sim.control.twist_rate = spin
        tick()
        watch()
    end
    stop()
    return true
end

--- act.retract{speed, depth | to}: pull the needle back at `speed` [m/s] until its tip is `depth`
-- [m] past the entry point, or back to the target named `to` (as act.insert's `to`: the target
-- is ahead of the tip again). Without either the needle comes all the way out, and on until its
-- tip is CLEAR (2 mm) outside the entry point, so the skin settling back does not meet it (a
-- needle that goes in again enters afresh: sim/coupling_reentry.c).
function act.retract(t)
    running()
    fields(t, "retract", { "speed", "depth", "to" })
    local speed = number(t, "retract", "speed", speed_ok, speed_what())
    local depth = number(t, "retract", "depth", GE0, ">= 0 [m]", -1)
    local togo = goal(t, "retract")
    local out = depth < 0 and t.to == nil
    local watch = stall_watch("act.retract: the needle does not come back", -1,
        out and -CLEAR or sim.depth + togo())
    while (out and (not sim.exited or sim.depth > -CLEAR)) or (not out and togo() < 0
        and not sim.exited) do
        sim.control.v_insert = -speed
        tick()
        watch()
    end
    stop()
end

-- Turns the base by angle [rad] at rate [rad/s], the insertion paused (the last step slower).
local function turn_base(angle, rate)
    local turned, sign = 0, angle < 0 and -1 or 1
    while turned < math.abs(angle) - 1e-12 do
        local w = math.min(rate, (math.abs(angle) - turned) / sim.dt)
        sim.control.v_insert = 0
        sim.control.twist_rate = sign * w
        turned = turned + w * sim.dt
        tick()
    end
    stop()
end

--- act.twist{angle, rate}: turn the needle's base by `angle` [rad] (signed) at `rate` [rad/s]
-- (default pi), the insertion paused.
function act.twist(t)
    running()
    fields(t, "twist", { "angle", "rate" })
    local angle = number(t, "twist", "angle", angle_ok,
        fmt("in [-%g, %g] [rad]", sim.limits.twist_angle, sim.limits.twist_angle))
    local rate = number(t, "twist", "rate", rate_ok, rate_what(), math.pi)
    turn_base(angle, rate)
end

-- The angle [rad] about the tip's direction from the bevel's direction (m2) to the target named
-- `to`, and the target's distance across the needle [m].
local function bevel_offset(to)
    local x, p, d, b = sim.targets[to], sim.tip, sim.tip_direction, sim.bevel_direction
    local e = { x[1] - p[1], x[2] - p[2], x[3] - p[3] }
    local ed = e[1] * d[1] + e[2] * d[2] + e[3] * d[3]
    for j = 1, 3 do
        e[j] = e[j] - ed * d[j]
    end
    local c = { b[2] * e[3] - b[3] * e[2], b[3] * e[1] - b[1] * e[3], b[1] * e[2] - b[2] * e[1] }
    local sn = c[1] * d[1] + c[2] * d[2] + c[3] * d[3]
    local cs = b[1] * e[1] + b[2] * e[2] + b[3] * e[3]
    return math.atan(sn, cs), math.sqrt(e[1] ^ 2 + e[2] ^ 2 + e[3] ^ 2)
end

--- act.aim{to, rate, within}: turn the needle's base at `rate` [rad/s] (default pi), the
-- insertion paused, until the bevel faces the target named `to` across the needle, within
-- `within` [rad] (default 0.2): a bevel-tip needle pushed in next cuts towards it. The tip's
-- bevel lags the base through the needle's torsion, so the base turns in steps of at most
-- 0.1 rad (a positive turn of the base turns the bevel positively about the tip's direction),
-- each checked against the bevel's direction; if the bevel is not aimed after 200 steps the
-- action fails at the script's line. Nothing turns if the target is within 0.1 mm of the
-- needle's line.
function act.aim(t)
    running()
    fields(t, "aim", { "to", "rate", "within" })
    if type(t.to) ~= "string" or sim.targets[t.to] == nil then
        error(fmt("act.aim: 'to' must name a target of the scenario (got %s)", tostring(t.to)), 2)
    end
    local rate = number(t, "aim", "rate", rate_ok, rate_what(), math.pi)
    local within = number(t, "aim", "within", GT0, "> 0 [rad]", 0.2)
    local phi, off = bevel_offset(t.to)
    local steps = 0
    while off >= 1e-4 and math.abs(phi) > within do
        if steps == 200 then
            error(fmt("act.aim: the bevel is still %.0f deg off the target '%s' after 200 turns",
                math.deg(math.abs(phi)), t.to), 2)
        end
        act.twist { angle = (phi < 0 and -1 or 1) * math.min(math.abs(phi), 0.1), rate = rate }
        phi, off = bevel_offset(t.to)
        steps = steps + 1
    end
    stop()
end

--- act.wait{time}: hold the needle still for `time` [s].
function act.wait(t)
    running()
    fields(t, "wait", { "time" })
    local time = number(t, "wait", "time", GE0, ">= 0 [s]")
    local n = math.floor(time / sim.dt + 0.5)
    stop()
    for _ = 1, n do
        tick()
    end
end

--- act.move_base{velocity, time}: move the needle's sleeve (its base and the entry guide) at
-- `velocity` {vx, vy, vz} [m/s] for `time` [s], the insertion and twist paused.
function act.move_base(t)
    running()
    fields(t, "move_base", { "velocity", "time" })
    local v = t.velocity
    local lim = sim.limits.base_speed
    if type(v) ~= "table" or #v ~= 3 or not (finite(v[1]) and finite(v[2]) and finite(v[3]))
        or math.abs(v[1]) > lim or math.abs(v[2]) > lim or math.abs(v[3]) > lim then
        error(fmt("act.move_base: velocity must be {vx, vy, vz}: 3 finite numbers in [-%g, %g] "
            .. "[m/s] (got %s)", lim, lim, tostring(v)), 2)
    end
    local time = number(t, "move_base", "time", GT0, "> 0 [s]")
    local n = math.floor(time / sim.dt + 0.5)
    for _ = 1, n do
        sim.control.v_insert = 0
        sim.control.twist_rate = 0
        sim.control.base_velocity = { v[1], v[2], v[3] }
        tick()
    end
    sim.control.base_velocity = nil
end

local function vec3(t, name, k, optional)
    local v = t[k]
    if v == nil and optional then
        return nil
    end
    if type(v) ~= "table" or #v ~= 3 or not (finite(v[1]) and finite(v[2]) and finite(v[3])) then
        error(fmt("act.%s: %s must be {x, y, z}: 3 finite numbers (got %s)", name, k,
            tostring(v)), 3)
    end
    return { v[1], v[2], v[3] }
end

--- act.next_needle{point, direction, bevel_toward}: the needle, withdrawn all the way, is
-- replaced by a new one of the same kind entering at `point` along `direction` (the next hole
-- of a template; fields as the scenario's `entry`). The tissue keeps its state, and the seeds
-- already released stay where they are. Takes one step.
function act.next_needle(t)
    running()
    fields(t, "next_needle", { "point", "direction", "bevel_toward" })
    local p = vec3(t, "next_needle", "point")
    local d = vec3(t, "next_needle", "direction")
    local b = vec3(t, "next_needle", "bevel_toward", true)
    local len = math.sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3])
    if len == 0 then
        error("act.next_needle: direction must not be zero", 2)
    end
    d = { d[1] / len, d[2] / len, d[3] / len }
    if b then
        local bd = b[1] * d[1] + b[2] * d[2] + b[3] * d[3]
        b = { b[1] - bd * d[1], b[2] - bd * d[2], b[3] - bd * d[3] }
        local lb = math.sqrt(b[1] * b[1] + b[2] * b[2] + b[3] * b[3])
        if lb == 0 then
            error("act.next_needle: bevel_toward must not be parallel to direction", 2)
        end
        b = { b[1] / lb, b[2] / lb, b[3] / lb }
    end
    if not sim.exited then
        error("act.next_needle: the needle is still in the tissue (act.retract{speed = ...} "
            .. "without a depth takes it all the way out first)", 2)
    end
    stop()
    sim.control.next_needle = { point = p, direction = d, bevel_toward = b }
    tick()
    fresh = true
    entry = { point = p, direction = d }
end

--- act.drop_seed{}: release a seed at the needle tip (brachytherapy). It stays in the tissue
-- where it was released and moves with it; the i-th seed released is scored against the
-- scenario's i-th planned seed's target (`seeds`), later ones against the nearest target.
function act.drop_seed(t)
    running()
    fields(t == nil and {} or t, "drop_seed", {})
    sim.control.drop_seed = true
    tick()
end

--- act.needle{hole, depth, load, speed, spin}: a preloaded needle through the template hole
-- named `hole` (the scenario's `template = ns.template{...}`). The needle before it comes out
-- first (unless it is the scenario's first needle, waiting unused at this very hole); the new
-- one is pushed in at `speed` [m/s] (default 0.02), turning at `spin` [rad/s] (default 0),
-- until its tip is `depth` [m] past the skin; then it is withdrawn with the stylet held, and
-- each seed of `load` ({"seed", "spacer", ...} from the tip back, or {seeds = n, spacing = s})
-- is released where the tip passes the place the seed held in the needle (the template's
-- seeds(hole, depth, load) are those places in the undeformed anatomy: the plan). Returns true,
-- or false when the tip met bone on the way in (pubic arch interference, counted in the
-- report): that needle comes out with its seeds and the script re-aims (another hole).
function act.needle(t)
    running()
    fields(t, "needle", { "hole", "depth", "load", "speed", "spin" })
    local tpl = sim.template
    if tpl == nil then
        error("act.needle: the scenario has no template (template = ns.template{...})", 2)
    end
    if type(t.hole) ~= "string" or tpl.holes[t.hole] == nil then
        error(fmt("act.needle: 'hole' must name a hole of the template (got %s; holes %s to %s)",
            tostring(t.hole), tpl.names[1], tpl.names[#tpl.names]), 2)
    end
    local depth = number(t, "needle", "depth", GT0, "> 0 [m]")
    local offs, why = tpl.offsets(t.load)
    if not offs then
        error("act.needle: " .. why, 2)
    end
    if offs[#offs] >= depth then
        error(fmt("act.needle: the load's last seed is %.1f mm behind the tip, past the skin at "
            .. "depth %.1f mm", 1e3 * offs[#offs], 1e3 * depth), 2)
    end
    local speed = number(t, "needle", "speed", speed_ok, speed_what(), 0.02)
    local spin = number(t, "needle", "spin", spin_ok,
        fmt("in [-%g, %g] [rad/s]", sim.limits.twist_rate, sim.limits.twist_rate), 0)
    local p, d = tpl.holes[t.hole], tpl.direction
    local e, ed = entry.point, entry.direction
    local here = math.abs(e[1] - p[1]) + math.abs(e[2] - p[2]) + math.abs(e[3] - p[3]) < 1e-9
        and math.abs(ed[1] - d[1]) + math.abs(ed[2] - d[2]) + math.abs(ed[3] - d[3]) < 1e-9
    if not (fresh and here) then
        if not sim.exited then
            act.retract { speed = speed }
        end
        act.next_needle { point = p, direction = d }
    end
    if not act.insert { speed = speed, depth = depth, spin = spin } then
        act.retract { speed = speed }
        return false
    end
    for _, off in ipairs(offs) do
        act.retract { speed = speed, depth = depth - off }
        act.drop_seed {}
    end
    act.retract { speed = speed }
    return true
end

-- The target named `to` (a string naming one of sim.targets), else an error at the caller's
-- caller's line listing the targets.
local function target_name(name, to, level)
    if type(to) ~= "string" or sim.targets[to] == nil then
        error(fmt("%s: 'target' must name a target of the scenario (got %s; targets: %s)",
            label(name), tostring(to), target_list()), level)
    end
    return to
end

-- A list of the scenario's obstacle names (or nil), checked.
local function avoid_list(name, avoid, level)
    if avoid == nil then
        return {}
    end
    local known = {}
    for _, n in ipairs(sim.planner.obstacles) do
        known[n] = true
    end
    if type(avoid) ~= "table" then
        error(fmt("%s: 'avoid' must be a list of obstacle names (got %s)", label(name),
            tostring(avoid)), level)
    end
    local out = {}
    for i, n in ipairs(avoid) do
        if not known[n] then
            error(fmt("%s: avoid[%d] = %s is not an obstacle of the scenario (obstacles: %s)",
                label(name), i, tostring(n), #sim.planner.obstacles > 0
                and table.concat(sim.planner.obstacles, ", ") or "none"), level)
        end
        out[i] = n
    end
    return out
end

local function method_field(name, m, level)
    if m == nil then
        return nil
    end
    if m ~= "helix" and m ~= "rrt" then
        error(fmt("%s: method must be \"helix\" or \"rrt\" (got %s)", label(name), tostring(m)),
            level)
    end
    return m
end

local function dot(a, b) return a[1] * b[1] + a[2] * b[2] + a[3] * b[3] end
local function copy3(a) return { a[1], a[2], a[3] } end

-- The planners' common fields from a steer or plan call, checked; `extra`: the calls between
-- the action and the script's line (0 for act.steer, 1 for ns.plan).
local function plan_fields(t, name, extra)
    local f, level = {}, 4 + extra
    f.target = target_name(name, t.target, level)
    f.avoid = avoid_list(name, t.avoid, level)
    f.clearance = number(t, name, "clearance", GE0, ">= 0 [m]", 1e-3, level)
    f.seed = number(t, name, "seed", function(x) return x >= 0 and x <= 1e9 and x % 1 == 0 end,
        "integer in 0..1e9", 1, level)
    f.method = method_field(name, t.method, level)
    return f
end

--- act.steer{target, avoid, clearance, replan_every, max_depth, method, speed, twist_rate,
-- seed, tolerance, rollout}: closed-loop steering (Hauser et al. 2009; docs/planning.md). Every
-- `replan_every` [m] of insertion (default 2 mm) it reads the tip's pose (position, direction,
-- bevel direction) and where the tissue has carried the target named `target`, asks the
-- planner for the twist and duty cycle whose predicted arc passes closest to it ("helix", the
-- default) or for the first action of an RRT around the obstacles named in `avoid` planned
-- from there ("rrt", keeping `clearance` [m] from them, default 1 mm), turns the base by the
-- twist (at `twist_rate` [rad/s], default 4 pi, the insertion paused), and inserts at `speed`
-- [m/s] (default 0.01): the bevel held for (1 - duty) of the segment, then spun one whole turn
-- over the rest (duty-cycled spinning). The curvature the planner predicts with is estimated
-- from the tip's measured turning while the bevel was held; with `rollout = true` it is
-- measured before each replan instead, by a rollout in the simulator (a copy of the world
-- stepped `replan_every`, at least 4 mm, at `speed` with the bevel held). It stops when the tip passes its
-- closest approach to the target (the target no longer ahead of it) or at `max_depth` [m] of
-- depth (default: the depth now plus 1.5 x the distance to the target). Returns the tip's
-- distance to the target at the end [m].
function act.steer(t)
    running()
    fields(t, "steer", { "target", "avoid", "clearance", "replan_every", "max_depth", "method",
        "speed", "twist_rate", "seed", "tolerance", "rollout" })
    local f = plan_fields(t, "steer", 0)
    local method = f.method or "helix"
    local every = number(t, "steer", "replan_every", function(x) return x >= 1e-4 and x <= 0.1 end,
        "in [1e-4, 0.1] [m]", 2e-3)
    local speed = number(t, "steer", "speed", speed_ok, speed_what(), 0.01)
    local twist_rate = number(t, "steer", "twist_rate", rate_ok, rate_what(), 4 * math.pi)
    local tol = number(t, "steer", "tolerance", GT0, "> 0 [m]", 1e-3)
    local rollout = t.rollout
    if rollout ~= nil and type(rollout) ~= "boolean" then
        error(fmt("act.steer: rollout must be true or false (got %s)", type(rollout)), 2)
    end
    local q0, p0 = sim.targets[f.target], sim.tip
    local far = math.sqrt((q0[1] - p0[1]) ^ 2 + (q0[2] - p0[2]) ^ 2 + (q0[3] - p0[3]) ^ 2)
    local max_depth = number(t, "steer", "max_depth", GT0, "> 0 [m]", sim.depth + 1.5 * far)
    local P = sim.planner
    local index = 0
    for i, n in ipairs(P.target_names or {}) do
        if n == f.target then index = i end
    end
    local kappa, turned, held = P.kappa, 0, 0
    -- the tip's path: arc length travelled [m] and positions, for the path's own tangent (a
    -- chord over the last CHORD metres: the tip's last edge leans towards the bevel more than
    -- the path it cuts, so its direction overstates the curvature)
    local CHORD, PRIOR, ROLLOUT_MIN = 6e-3, 10, 4e-3
    local trail_p = { copy3(sim.tip) }
    local function chord()
        local n = #trail_p
        local b, k, c, l = trail_p[n], n, { 0, 0, 0 }, 0
        while k > 1 and l < CHORD do -- back until the chord is CHORD long (not travel: jitter)
            k = k - 1
            local a = trail_p[k]
            c = { b[1] - a[1], b[2] - a[2], b[3] - a[3] }
            l = math.sqrt(dot(c, c))
        end
        if l < 0.5 * CHORD then
            return nil
        end
        return { c[1] / l, c[2] / l, c[3] / l }
    end
    local last = copy3(sim.tip_direction)
    -- The tip's direction, a one-step reversal not believed (as act.insert's `to`).
    local function dir()
        local d = sim.tip_direction
        if dot(d, last) < 0 then
            return last
        end
        last = copy3(d)
        return last
    end
    local function track()
        P.track { tip = sim.tip, avoid = f.avoid, target_index = index }
    end
    -- The target is no longer ahead of the tip, along its direction or along the path it has
    -- cut (a tip that turned sideways round the target never has it behind its direction), or
    -- the depth is spent.
    local function done()
        local q, p = sim.targets[f.target], sim.tip
        local e = { q[1] - p[1], q[2] - p[2], q[3] - p[3] }
        local c = chord()
        return dot(e, dir()) <= 0 or (c and dot(e, c) <= 0) or sim.depth >= max_depth
    end
    local watch = stall_watch("act.steer: the needle does not advance", 1, max_depth)
    -- Inserts `len` [m] of tip travel with the base turning at `spin` [rad/s] for `n` steps
    -- (spin 0: until the length is done). Returns the tip's travel [m].
    local function advance(len, v, spin, n)
        local moved, prev, k = 0, copy3(sim.tip), 0
        while not done() and ((n and k < n) or (not n and moved < len)) do
            if sim.bone_contact then
                return moved
            end
            sim.control.v_insert = v
            sim.control.twist_rate = spin
            tick()
            watch()
            track()
            local p = sim.tip
            local dm = math.sqrt((p[1] - prev[1]) ^ 2 + (p[2] - prev[2]) ^ 2 + (p[3] - prev[3]) ^ 2)
            moved = moved + dm
            prev = copy3(p)
            trail_p[#trail_p + 1] = copy3(p)
            k = k + 1
        end
        return moved
    end
    track()
    local replans = 0
    while not done() and not sim.bone_contact do
        if rollout then -- the curvature a copy of the world gives the needle from here
            local ok, ro = pcall(P.rollout, { length = math.max(every, ROLLOUT_MIN), speed = speed })
            if not ok then -- said at the scenario's line, not this file's
                error((tostring(ro):gsub("^[^\n]-:%d+: ", "")), 2)
            end
            kappa = math.max(0.05 * P.kappa, math.min(3 * P.kappa, ro.kappa))
        end
        local a = P.choose { tip = sim.tip, t = dir(), m2 = sim.bevel_direction,
            target = sim.targets[f.target], kappa = kappa, method = method, avoid = f.avoid,
            clearance = f.clearance, tolerance = tol, seed = f.seed + replans }
        replans = replans + 1
        if math.abs(a.twist) > 1e-3 then
            turn_base(a.twist, twist_rate)
        end
        local seg = math.min(every, max_depth - sim.depth)
        local c0, b0 = chord(), copy3(sim.bevel_direction)
        local h = advance((1 - a.duty) * seg, speed, 0)
        -- the spun part: one whole turn over duty x seg, at most the twist-rate limit
        local steps = math.floor(a.duty * seg / (speed * sim.dt) + 0.5)
        if steps >= 1 and not done() then
            local n = math.max(steps, math.ceil(2 * math.pi / (sim.limits.twist_rate * sim.dt)))
            advance(0, a.duty * seg / (n * sim.dt), 2 * math.pi / (n * sim.dt), n)
        end
        stop()
        -- The curvature seen while the bevel was held (the model's is not the tissue's): the
        -- path's turn m towards the bevel over the segment (signed, so that the jitter of the
        -- tip's position cancels instead of adding up) against the held length h, by least
        -- squares: kappa = sum(h m) / sum(h^2). Segments spun nearly all the way (h small) then
        -- weigh little: their turn is mostly noise, and as a ratio of sums they fed the
        -- estimate's own growth (a higher estimate, more spinning, a smaller h). The sums start
        -- as if PRIOR segments held all the way had turned at the model's curvature.
        local c1 = chord()
        if c0 and c1 then
            turned = turned + h * dot({ c1[1] - c0[1], c1[2] - c0[2], c1[3] - c0[3] }, b0)
            held = held + h * h
        end
        local prior = PRIOR * every * every
        if not rollout then
            kappa = math.max(0.5 * P.kappa, math.min(2 * P.kappa,
                (turned + P.kappa * prior) / (held + prior)))
        end
    end
    stop()
    P.finish() -- its predicted arc is no longer drawn in the frames
    local q, p = sim.targets[f.target], sim.tip
    return math.sqrt((q[1] - p[1]) ^ 2 + (q[2] - p[2]) ^ 2 + (q[3] - p[3]) ^ 2)
end

-- ns.plan{target, avoid, clearance, method, seed} (needlesim.lua) while the scenario runs.
function act._plan(t)
    if sim == nil or sim.planner == nil then
        error("ns.plan: plans are made only while the scenario runs (in its script or on_tick)",
            3)
    end
    if type(t) ~= "table" then
        error(fmt("ns.plan: expected a table of fields {target, avoid, clearance, method, seed} "
            .. "(got %s)", type(t)), 3)
    end
    for k in pairs(t) do
        if k ~= "target" and k ~= "avoid" and k ~= "clearance" and k ~= "method" and k ~= "seed"
        then
            error(fmt("ns.plan: unknown field '%s' (known: target, avoid, clearance, method, seed)",
                tostring(k)), 3)
        end
    end
    local f = plan_fields(t, "ns.plan", 1)
    local method = f.method or "rrt"
    local tol = 1e-3
    return sim.planner.plan { tip = sim.tip, t = sim.tip_direction, m2 = sim.bevel_direction,
        target = sim.targets[f.target], method = method, avoid = f.avoid,
        clearance = f.clearance, tolerance = tol, seed = f.seed }
end

-- ---- the video's voice (docs/rendering.md "Authored videos") ----
-- These change the pictures of a run with --video (or --frames), never the physics: they queue
-- a cue for the engine and return at once, taking no simulated time, so a run's state hash is
-- the same with them, without them and with --no-render.

local function cue(c)
    local q = sim.control.video
    if type(q) ~= "table" then
        q = {}
        sim.control.video = q
    end
    q[#q + 1] = c
end

local function text(t, name, k, optional)
    local v = t[k]
    if v == nil and optional then
        return nil
    end
    if type(v) ~= "string" or #v == 0 or #v > sim.limits.video_text or v:find("\0", 1, true) then
        error(fmt("act.%s: %s must be a non-empty string of at most %d bytes (got %s)", name, k,
            sim.limits.video_text, type(v) == "string" and fmt("%d bytes", #v) or type(v)), 3)
    end
    return v
end

local function within(lo, hi)
    return function(x) return x >= lo and x <= hi end
end

-- A field in [lo, hi] (hi a name in sim.limits or a number), its unit in the message.
local function ranged(t, name, k, lo, hi, unit, default)
    hi = type(hi) == "string" and sim.limits[hi] or hi
    local v = number(t, name, k, within(lo, hi), fmt("in [%g, %g]%s", lo, hi, unit), default, 4)
    return v -- (not a tail call: the error's level counts this function)
end

--- act.caption{text, duration}: `text` on screen for the next `duration` [s] of simulated time
-- (a later caption replaces it).
function act.caption(t)
    running()
    fields(t, "caption", { "text", "duration" })
    cue { kind = "caption", text = text(t, "caption", "text"),
        duration = ranged(t, "caption", "duration", 1e-3, "video_duration", " [s]") }
end

--- act.chapter{title}: a chapter of the video, titled `title`, starts here (an MP4 chapter).
function act.chapter(t)
    running()
    fields(t, "chapter", { "title" })
    cue { kind = "chapter", title = text(t, "chapter", "title") }
end

--- act.slow_motion{factor, duration}: the next `duration` [s] of simulated time shown `factor`
-- times slower (more frames a simulated second).
function act.slow_motion(t)
    running()
    fields(t, "slow_motion", { "factor", "duration" })
    cue { kind = "slow_motion", factor = ranged(t, "slow_motion", "factor", 1, "video_slow", ""),
        duration = ranged(t, "slow_motion", "duration", 1e-3, "video_duration", " [s]") }
end

--- act.camera{view | views, zoom, orbit, duration}: the video's views from here ("side", "top",
-- "axis", or a list of up to three side by side), zoomed `zoom` times about the needle tip and
-- turned `orbit` degrees more about the insertion axis (side and top views), reached over
-- `duration` [s] of simulated time (default 0: at once).
function act.camera(t)
    running()
    fields(t, "camera", { "view", "views", "zoom", "orbit", "duration" })
    local views = t.views
    if t.view ~= nil then
        if views ~= nil then
            error("act.camera: give `view` or `views`, not both", 2)
        end
        views = { t.view }
    end
    if views ~= nil then
        if type(views) ~= "table" or #views < 1 or #views > 3 then
            error("act.camera: views must list one to three view names", 2)
        end
        for i, v in ipairs(views) do
            if v ~= "side" and v ~= "top" and v ~= "axis" and v ~= "cutaway3d" and v ~= "trus" then
                error(fmt("act.camera: view %d must be \"side\", \"top\", \"axis\", " ..
                    "\"cutaway3d\" or \"trus\" (got %s)", i, tostring(v)), 2)
            end
        end
    end
    local zmax, omax = sim.limits.video_zoom, sim.limits.video_orbit
    cue { kind = "camera", views = views,
        zoom = t.zoom ~= nil and ranged(t, "camera", "zoom", 1 / zmax, zmax, "") or nil,
        orbit = t.orbit ~= nil and ranged(t, "camera", "orbit", -omax, omax, " [deg]") or nil,
        duration = ranged(t, "camera", "duration", 0, "video_duration", " [s]", 0) }
end

--- act.card{title, text, duration}: a title card (the title, `text` below it) for `duration`
-- [s] of the video (default 3), the simulation paused meanwhile: a lesson's opening and
-- closing.
function act.card(t)
    running()
    fields(t, "card", { "title", "text", "duration" })
    cue { kind = "card", title = text(t, "card", "title"), text = text(t, "card", "text", true),
        duration = ranged(t, "card", "duration", 0.1, "video_card", " [s]", 3) }
end

-- For the engine: binds the run's `sim` table and returns the script's coroutine (nil without
-- a script), which the engine resumes once per time step before the solver steps.
function act._bind(s, script)
    sim = s
    fresh = true
    entry = s.entry
    co = script and coroutine.create(script) or nil
    return co
end

return act
