-- A rollout in the simulator (docs/planning.md, "Rollouts in the simulator"): 10 mm in, then
-- sim.planner.rollout{length = 4 mm, speed = 20 mm/s} steps a copy of the world; the run then
-- takes the same steps itself (the bevel held, the same speed). The copy steps from the same
-- bytes to the same states, so the rollout's end is where the tip then goes, bit for bit;
-- --set rollout=false leaves the call out (the run's own state must not change with it).
local ns = require "needlesim"
local ROLLOUT = ns.param("rollout", true)
local ro, p0, n
local h = 0.005
return ns.scenario {
    name = "rollout",
    dt = 0.01,
    tissue = ns.tissue.box { size = { 8 * h, 8 * h, 10 * h }, origin = { -4 * h, -4 * h, 0 },
        resolution = h, material = ns.materials.gel, fixed_faces = { "zmax" } },
    needle = ns.needle { kind = "flexible", bevel_deg = 30, steering = ns.param("steering", "force") },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 }, bevel_toward = { 0, 1, 0 } },
    duration = 0.8,
    on_tick = function(sim)
        if not p0 and sim.depth < 0.01 then -- in to 10 mm at 20 mm/s
            sim.control.v_insert = 0.02
            return
        end
        if not p0 then
            if ROLLOUT then
                ro = sim.planner.rollout { length = 4e-3, speed = 0.02 }
            end
            p0, n = { sim.tip[1], sim.tip[2], sim.tip[3] }, 0
        end
        if n < 20 then -- the same 20 steps as the rollout: 20 mm/s, the bevel held
            sim.control.v_insert = 0.02
            sim.control.twist_rate = 0
            n = n + 1
            return
        end
        sim.control.v_insert = 0
        if n == 20 and ro then
            local p = sim.tip
            print(string.format("rollout: %d steps, kappa %.6f 1/m, out of plane %.3g m, end "
                .. "%.17g %.17g %.17g; the run's tip %.17g %.17g %.17g", ro.steps, ro.kappa,
                ro.out_of_plane, ro.tip[1], ro.tip[2], ro.tip[3], p[1], p[2], p[3]))
        end
        n = n + 1
    end,
}
