local ns = require "needlesim"
-- Dosimetry of a small made-up anatomy, planned from a list (tests/test_run.sh; tests/test_cli.sh
-- puts the second seed outside the tissue with --set seed2_z=0.5).
local s = ns.shape
local block = s.box { center = { 0, 0, 0.01 }, size = { 0.03, 0.03, 0.02 } }
return ns.scenario {
    name = "small dosimetry",
    tissue = ns.tissue.shapes { resolution = 0.004, regions = {
        { name = "fat", shape = block, material = ns.materials.fat, fixed = true },
        { name = "prostate", shape = s.sphere { center = { 0, 0, 0.01 }, radius = 0.006 },
          material = ns.materials.prostate },
        { name = "urethra", shape = s.sphere { center = { 0.008, 0.008, 0.01 }, radius = 0.004 },
          material = ns.materials.urethra },
        { name = "rectum", shape = s.sphere { center = { -0.008, -0.008, 0.01 }, radius = 0.004 },
          material = ns.materials.rectum },
    } },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    dosimetry = { plan = { { 0, 0, 0.01 }, { 0.002, 0, ns.param("seed2_z", 0.01) } } },
}
