-- A small two-region tissue for the command-line tests: a 3 x 2 x 2 cm block of fat with a
-- fixed ball of bone inside (mesh output and the .msh round trip).
local ns = require "needlesim"

local block = ns.shape.box { center = { 0.015, 0.01, 0.01 }, size = { 0.03, 0.02, 0.02 } }
return ns.scenario {
    name = "small shapes",
    tissue = ns.tissue.shapes {
        resolution = 0.004,
        bounds = { { 0, 0, 0 }, { 0.032, 0.02, 0.02 } },
        regions = {
            { name = "fat", shape = block, material = ns.materials.fat },
            { name = "ball", material = ns.materials.bone, fixed = true,
                shape = ns.shape.sphere { center = { 0.015, 0.01, 0.01 }, radius = 0.005 } },
        },
    },
}
