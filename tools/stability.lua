-- The stability map's scene (tools/stability_map.py, docs/performance.md): a stiff symmetric
-- needle into a gel block along its centre line, steadily or vigorously back and forth. Every
-- knob is a parameter:
--   dt           time step [s]                       (0.01)
--   youngs       the gel's Young's modulus [Pa]      (20e3): the needle/tissue stiffness ratio
--   speed        insertion speed [m/s]               (0.02)
--   vigorous     true: 5 mm in, 3 mm back, again, to the depth (the paper's video "vigorously")
--   needle       "stiff" (steel, symmetric tip) or "flexible" (nitinol, bevel tip)
--   cut_force    the gel's cutting force [N]          (0.3 x youngs / 20 kPa)
--   friction     needle-gel friction [N/m]            (30 x youngs / 20 kPa)
--   bevel_force  the flexible needle's k_b [N]        (0.5 x youngs / 20 kPa)
-- The cutting force, the friction and the bevel's lateral force scale with the modulus: all
-- three are set by the stress that opens the gel around a needle of a given size, which for a
-- gel of a given strain to failure is proportional to its modulus (0.3 N and 30 N/m at 20 kPa,
-- the gel of scripts/needlesim/materials.lua; k_b 0.5 N, the default, at 20 kPa). Held at 0.3 N and 30 N/m, a 1-2 kPa gel cannot give the tip 0.3 N before
-- it is indented centimetres (docs/performance.md, "Stability map").
-- The stiff needle should stay on the line: the lateral tip deviation is the run's error.
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.005
local speed = ns.param("speed", 0.02)
local vigorous = ns.param("vigorous", false)
local depth = 0.03
local youngs = ns.param("youngs", 20e3)

return ns.scenario {
    name = "stability map cell",
    dt = ns.param("dt", 0.01),
    tissue = ns.tissue.box {
        size = { 8 * h, 8 * h, 10 * h },
        origin = { -4 * h, -4 * h, 0 },
        resolution = h,
        material = ns.material {
            name = "gel", youngs = youngs, poisson = 0.45, density = 1040, damping = 5,
            friction = ns.param("friction", 30 * youngs / 20e3),
            cut_force = ns.param("cut_force", 0.3 * youngs / 20e3),
        },
        fixed_faces = { "zmax" },
    },
    needle = ns.param("needle", "stiff") == "flexible"
        and ns.needle { kind = "flexible", bevel_force = ns.param("bevel_force", 0.5 * youngs / 20e3) }
        or ns.needle { kind = "stiff" },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    script = function()
        if vigorous then
            local d = 0.0
            while d < depth do
                d = math.min(depth, d + 0.005)
                act.insert { speed = speed, depth = d }
                if d < depth then
                    act.retract { speed = speed, depth = d - 0.003 }
                end
            end
        else
            act.insert { speed = speed, depth = depth }
        end
        act.wait { time = 0.1 }
    end,
}
