-- An endless loop inside a shape function, caught while the mesher runs.
local ns = require "needlesim"
return ns.scenario {
    name = "endless shape",
    tissue = ns.tissue.shapes {
        resolution = 0.004,
        bounds = { { 0, 0, 0 }, { 0.02, 0.02, 0.02 } },
        regions = { { name = "blob", material = ns.materials.gel, shape = function(x, y, z)
            while true do end
        end } },
    },
}
