-- Prostate brachytherapy (paper §4, Figure 1): transperineal needle insertion into the
-- prostate through the perineum, with the urethra to spare and the pubic arch in the way.
--
-- What it teaches: the tissue the needle crosses on the way in (skin, perineal fat and muscle,
-- the prostate capsule) and the structures to avoid (urethra, rectum, pubic arch).
--
-- The anatomy is synthetic, built from textbook dimensions (scripts/needlesim/anatomy.lua says
-- which), in a patient frame: x patient left (+) / right (-); y anterior (+, towards the pubis) /
-- posterior (-, rectum); z depth from the perineal skin (z = 0) towards the bladder (+). Metres.
--
-- The run (needlesim run scenarios/brachytherapy.lua): two needles, one after the other, through
-- the template holes at x = +8 and -10 mm, y = -4 mm (either side of the urethra, above the
-- rectum) into the prostate, each guided as on transrectal ultrasound: in, spun, for 3 cm; the
-- bevel then turned towards the base seed's target (the prostate moves away from the needle as
-- it goes in) and the needle pushed on until its tip reaches the target where the tissue has
-- carried it; a seed left there, back to the mid seed's target, a second seed, then all the way
-- out. A flexible bevel-tip needle by default (the paper's ProsFB; `--set needle.kind=stiff` is
-- its ProsSS, whose symmetric tip does not steer). The urethra, rectum and pubic arch are
-- obstacles; each one entered costs 25 points.
local ns = require "needlesim"
local act = require "needlesim.actions"
local pelvis = require("needlesim.anatomy").pelvis()

-- The template holes (x, y on the perineum) and the planned seed depths from the skin [m] (the
-- targets; the needle punctures the skin at the hole, docs/remeshing.md "Skin entry").
local holes = { { 0.008, -0.004 }, { -0.010, -0.004 } }
local seed_depths = { 0.060, 0.048 }

local targets, seeds = {}, {}
for i, hole in ipairs(holes) do
  for k, depth in ipairs(seed_depths) do
    local name = string.format("%s seed %d", k == 1 and "base" or "mid", i)
    targets[#targets + 1] = { name = name, at = { hole[1], hole[2], depth }, tolerance = 3e-3 }
    seeds[#seeds + 1] = { target = name } -- in the order the script drops them
  end
end

return ns.scenario {
  name = "prostate brachytherapy",
  description = "Transperineal insertion into a synthetic male pelvis (paper Fig. 1).",
  dt = ns.param("dt", 0.01),
  -- The engine's defaults, settable for tools/speed_accuracy.py (docs/performance.md).
  solver = {
    tolerance = ns.param("solver.tolerance", 1e-8),
    -- checked a hundred times looser, as the paper does (1e-3 and 1e-5)
    check_tolerance = math.min(0.5, 100 * ns.param("solver.tolerance", 1e-8)),
    lazy_threshold = ns.param("solver.lazy_threshold", 1e-2),
    -- the stale factor's block at the tip made current every step (docs/solvers.md)
    tip_block = ns.param("solver.tip_block", false),
  },
  -- `needlesim run ... --set needle.kind=stiff` runs the stiff symmetric needle (ProsSS).
  needle = ns.needle { kind = ns.param("needle.kind", "flexible"), bevel_deg = 30 },
  entry = { point = { holes[1][1], holes[1][2], 0 }, direction = { 0, 0, 1 } },
  targets = targets,
  seeds = seeds,
  -- The seeds' TG-43 dose, planned (at the targets) against delivered (where the tissue left
  -- them): report.json's `dosimetry`, DIR/dvh.csv (docs/brachytherapy.md). Four seeds cover
  -- only a corner of the gland; scenarios/brachytherapy_implant.lua is the full implant.
  dosimetry = { prescription = 145, strength = 0.5 },
  obstacles = {
    { name = "urethra", region = "urethra" },
    { name = "rectum", region = "rectum" },
    { name = "pubic arch", region = "pubic_arch" },
  },
  -- a live session (`needlesim live`, docs/live.md) steps at the cheapest setting measured
  -- on the brachytherapy front within 1.5 mm at the seeds, half the targets' 3 mm tolerance
  -- (dt 40 ms: the step's cost then fits in real time on two cores); `needlesim run` keeps
  -- the dt above
  live = { accuracy = 1.5e-3, front = "brachytherapy" },
  script = function()
    for i, hole in ipairs(holes) do
      if i > 1 then
        act.next_needle { point = { hole[1], hole[2], 0 }, direction = { 0, 0, 1 } }
      end
      local base, mid = string.format("base seed %d", i), string.format("mid seed %d", i)
      -- 20 mm/s, spun at 1 turn/s (straight) through the perineum; then the bevel turned to
      -- face the base seed's target and the needle pushed on, unspun, until it reaches it
      act.insert { speed = 0.02, depth = 0.03, spin = 2 * math.pi }
      act.aim { to = base }
      act.insert { speed = 0.02, to = base }
      act.drop_seed {}
      act.retract { speed = 0.02, to = mid }
      act.drop_seed {}
      act.retract { speed = 0.02 } -- all the way out
    end
    act.wait { time = 0.2 } -- the tissue settles around the seeds
  end,
  tissue = pelvis.tissue,
}
