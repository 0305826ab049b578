-- Gel phantom, double bend (the paper's §4 validation, its Figure 9): the single-bend run's
-- block, needle and markers (phantom_single_bend.lua), but the robot turns the needle's base by
-- 180 degrees at half depth, so the bevel steers the other way and the path becomes an S.
--
-- What it teaches: reusing another scenario (a plain `require` of a file beside this one gives
-- its ns.scenario table), act.twist, and the needle's steering model. The bevel force (the
-- single bend's) reverses the bend only a bending length (~2 cm here) after the twist; the
-- nonholonomic arc model used here reverses it where the base turned (docs/remeshing.md,
-- validation case double-bend). `--set needle.steering=force` runs it with the force.
local ns = require "needlesim"
local act = require "needlesim.actions"
local single = require "phantom_single_bend"

return ns.scenario {
    name = "gel phantom, double bend",
    description = "the single-bend phantom with a 180 degree twist at 5 cm (Chentanez et al. 2009, §4, Fig. 9)",
    tissue = single.tissue,
    dt = single.dt,
    needle = ns.needle { kind = "flexible", bevel_deg = single.needle.bevel_deg,
        steering = ns.param("needle.steering", "arc") },
    entry = single.entry,
    markers = single.markers,
    camera = single.camera,
    script = function()
        act.insert { speed = 0.01, depth = 0.05 }
        act.twist { angle = math.pi, rate = math.pi / 0.2 } -- half a turn in 0.2 s, paused
        act.insert { speed = 0.01, depth = 0.10 }
        act.wait { time = 0.5 }
    end,
}
