-- A Lua function shape that fails while the mesher calls it.
local ns = require "needlesim"

local function blob(x, y, z)
    local r = math.sqrt((x - 0.01) ^ 2 + (y - 0.01) ^ 2 + (z - 0.01) ^ 2)
    return r - radius_of_blob -- undefined global: fails at run time, on line 6
end

return ns.scenario {
    name = "bad shape function",
    tissue = ns.tissue.shapes {
        resolution = 0.004,
        bounds = { { 0, 0, 0 }, { 0.02, 0.02, 0.02 } },
        regions = { { name = "blob", shape = blob, material = ns.materials.gel } },
    },
}
