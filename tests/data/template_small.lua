local ns = require "needlesim"
local act = require "needlesim.actions"
-- A template and two preloaded needles in a small made-up anatomy (tests/test_run.sh): holes
-- named and placed as ns.template says, each needle leaving its load's seeds at the template's
-- planned places (seeds(hole, depth, load)), the plan the dosimetry's.
local s = ns.shape
local tpl = ns.template { origin = { -0.003, -0.003, 0 }, spacing = 3e-3, cols = 3, rows = 3,
  labels = { cols = { "a", "b", "c" }, rows = { "1", "1.5", "2" } } }
-- the template's own arithmetic, checked where the scenario is read
assert(#tpl.names == 9 and tpl.names[1] == "a1" and tpl.names[2] == "a1.5", tpl.names[2])
local c2 = tpl.hole("c2")
assert(math.abs(c2[1] - 0.003) < 1e-15 and math.abs(c2[2] - 0.003) < 1e-15 and c2[3] == 0)
local load = { "seed", "spacer", "seed" }
local planned = tpl.seeds("a1", 0.02, load)
assert(#planned == 2 and math.abs(planned[1][3] - 0.01775) < 1e-12
  and math.abs(planned[2][3] - 0.00775) < 1e-12, planned[2][3])
local offs = tpl.offsets { seeds = 3, spacing = 6e-3 }
assert(#offs == 3 and math.abs(offs[3] - 0.01425) < 1e-12)
assert(not pcall(tpl.hole, "z9"))

local targets, seeds = {}, {}
for _, hole in ipairs { "a1", "c2" } do
  for i, at in ipairs(tpl.seeds(hole, 0.02, load)) do
    targets[#targets + 1] = { name = hole .. " seed " .. i, at = at, tolerance = 2e-3 }
    seeds[#seeds + 1] = { target = hole .. " seed " .. i }
  end
end
return ns.scenario {
  name = "template and preloaded needles",
  tissue = ns.tissue.shapes { resolution = 0.004, regions = {
    { name = "fat", shape = s.box { center = { 0, 0, 0.015 }, size = { 0.03, 0.03, 0.03 } },
      material = ns.materials.fat },
    { name = "prostate", shape = s.sphere { center = { 0, 0, 0.013 }, radius = 0.008 },
      material = ns.materials.prostate },
    { name = "urethra", shape = s.sphere { center = { 0.009, 0.009, 0.02 }, radius = 0.003 },
      material = ns.materials.urethra },
    { name = "rectum", shape = s.sphere { center = { -0.009, -0.009, 0.02 }, radius = 0.003 },
      material = ns.materials.rectum },
    { name = "bone", shape = s.box { center = { 0, 0, 0.029 }, size = { 0.03, 0.03, 0.004 } },
      material = ns.materials.bone, fixed = true },
  } },
  needle = ns.needle { kind = "stiff" },
  template = tpl,
  entry = tpl.entry("a1"),
  targets = targets,
  seeds = seeds,
  dosimetry = { prescription = 145 },
  script = function()
    assert(act.needle { hole = "a1", depth = 0.02, load = load })
    assert(act.needle { hole = "c2", depth = 0.02, load = load, speed = 0.03 })
  end,
}
