local ns = require "needlesim"
-- ns.plan_implant on the implant's pelvis (docs/planning.md, "Implant planning"): --set
-- case=good plans and checks the plan here (independently of the planner: the seeds in the
-- gland's ellipsoid, 1 cm apart on their hole's track, clear of the urethra's capsule and of the
-- rectum's); the other cases are bad calls, each refused at its own line.
local case = ns.param("case", "good")
local pelvis = require("needlesim.anatomy").pelvis { prostate_radii = { 0.024, 0.017, 0.020 } }
local template = ns.template { origin = { -0.020, -0.0125, 0 }, spacing = 5e-3, cols = 9, rows = 6 }
local base = { tissue = pelvis.tissue, template = template, region = "prostate",
  avoid = { "urethra", "rectum", "pubic_arch" }, strength = 0.37 }
local function with(k, v)
  local t = {}
  for key, val in pairs(base) do t[key] = val end
  t[k] = v
  return t
end
if case == "misspelt" then
  ns.plan_implant(with("regoin", "prostate"))
elseif case == "region" then
  ns.plan_implant(with("region", "prostrate"))
elseif case == "avoid_self" then
  ns.plan_implant(with("avoid", { "urethra", "prostate" }))
elseif case == "tissue" then
  ns.plan_implant(with("tissue", ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
    material = ns.materials.gel }))
elseif case == "coverage" then
  ns.plan_implant(with("coverage", 2))
elseif case == "clearance" then
  ns.plan_implant(with("clearance", 0.09))
elseif case == "raw" then
  -- the engine's half called directly with what the Lua half would refuse: each refused
  local raw = __ns_plan_implant
  local box = ns.shape.box { center = { 0, 0, 0 }, size = { 1, 1, 1 } }
  local good = { regions = { box, pelvis.shapes.prostate }, target = 2, avoid = {},
    holes = { { 0, 0, 0 } }, direction = { 0, 0, 1 }, clearance = 0, seeds = 10, needles = 1,
    spacing = 0.01, margin = 0, prescription = 145, strength = 0.5, coverage = 0.5,
    v150_max = 60, grid = 4e-3, seeds_per_needle = 20, tip_offset = 2.25e-3 }
  local huge = ns.shape.sphere { center = { 0, 0, 0 }, radius = 1e300 }
  local long = ns.shape.box { center = { 0, 0, 0.05 }, size = { 1e4, 0.01, 0.01 } }
  local bad = { -- each change, and what the refusal must say
    { { target = 1e300 }, "the target region is not one of the regions" },
    { { target = -3 }, "the target region is not one of the regions" },
    { { target = 2.5 }, "the target region is not one of the regions" },
    { { seeds = 2 ^ 62 }, "budgets must be >= 1" },
    { { needles = "x" }, "budgets must be >= 1" },
    { { seeds_per_needle = 0 }, "budgets must be >= 1" },
    { { avoid = { 1e300, -1 } }, "an avoided region is not one of the regions" },
    { { avoid = { 2 } }, "an avoided region is not one of the regions, or is the target" },
    { { holes = { { 0, 0 } } }, "holes[1] must be {x, y, z}" },
    { { holes = {} }, "the template has 0 holes" },
    { { holes = { { 0 / 0, 0, 0 } } }, "a hole is not a finite point" },
    { { holes = { { 0, 0, -1e9 } } }, "hole 1 is more than 1 m from the target region's box" },
    { { direction = { 0, 0, 0 } }, "the direction must be a finite non-zero vector" },
    { { regions = { 1, 2 } }, "expected a shape" },
    { { regions = {} }, "the tissue has 0 regions" },
    { { regions = { box, huge } }, "more than 1 m across" },
    { { regions = { box, long } }, "more than 1 m across" },
    { { grid = 0 }, "the planning grid must be in" },
    { { grid = 1e-9 }, "the planning grid must be in" },
    { { spacing = -1 }, "spacing must be in" },
    { { tip_offset = 1 }, "the tip's offset must be in" },
    { { strength = 0 / 0 }, "a strength > 0" },
    { { regions = { box, function(x, y, z) return 1 end } }, "shaped by a Lua function" },
  }
  local refused = 0
  for i, case in ipairs(bad) do
    local t = {}
    for k, v in pairs(good) do t[k] = v end
    for k, v in pairs(case[1]) do t[k] = v end
    local r, why = raw(t)
    assert(r == nil and type(why) == "string", "bad call " .. i .. " was not refused")
    assert(why:find(case[2], 1, true), "bad call " .. i .. ": " .. why)
    refused = refused + 1
  end
  assert(raw(good), "the good raw call failed")
  print(string.format("raw: %d bad calls refused, the good one planned", refused))
elseif case == "good" then
  local plan = ns.plan_implant(base)
  local function near_segment(p, a, b)
    local d = { b[1] - a[1], b[2] - a[2], b[3] - a[3] }
    local t = ((p[1] - a[1]) * d[1] + (p[2] - a[2]) * d[2] + (p[3] - a[3]) * d[3])
      / (d[1] ^ 2 + d[2] ^ 2 + d[3] ^ 2)
    t = math.max(0, math.min(1, t))
    return math.sqrt((p[1] - a[1] - t * d[1]) ^ 2 + (p[2] - a[2] - t * d[2]) ^ 2
      + (p[3] - a[3] - t * d[3]) ^ 2)
  end
  local k, total = 0, 0
  for _, n in ipairs(plan.needles) do
    local h = template.hole(n.hole)
    total = total + n.load.seeds
    for i = 1, n.load.seeds do
      k = k + 1
      local s = plan.seeds[k]
      assert(s[1] == h[1] and s[2] == h[2], "a seed off its hole's track")
      assert(math.abs(s[3] - (n.depth - 2.25e-3 - (i - 1) * 1e-2)) < 1e-12, "seed spacing")
      local q = (s[1] / 0.024) ^ 2 + (s[2] / 0.017) ^ 2 + ((s[3] - 0.050) / 0.020) ^ 2
      assert(q < 1, "a seed outside the gland")
      -- the urethra's capsule (radius 5 mm) and the rectum's (radius 10 mm), 2 mm clear
      assert(near_segment(s, { 0, 0.004, 0.026 }, { 0, 0.004, 0.076 }) >= 7e-3, "urethra")
      assert(near_segment(s, { 0, -0.029, 0.014 }, { 0, -0.029, 0.072 }) >= 12e-3, "rectum")
    end
  end
  assert(k == #plan.seeds and total == #plan.seeds, "seed count")
  print(string.format("implant plan: %d needles, %d seeds, V100 %.1f %%, V150 %.1f %%, "
    .. "D90 %.1f Gy, reached %s, %d candidates, %d blocked", #plan.needles, #plan.seeds,
    plan.v100, plan.v150, plan.d90, tostring(plan.reached), plan.candidates, plan.blocked))
end
return ns.scenario {
  name = "implant planning",
  tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
    material = ns.materials.gel, fixed_faces = { "zmax" } },
}
