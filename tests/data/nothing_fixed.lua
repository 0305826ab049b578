-- A tissue with nothing held in place: `check` and `run` refuse it (issue 32), naming this line
-- and how to hold it.
local ns = require "needlesim"
return ns.scenario {
    name = "nothing fixed",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.012 }, resolution = 0.004,
        material = ns.materials.gel },
}
