-- Loads mesh.msh from this scenario's folder (the test copies it there): the .msh round trip
-- of small_shapes.lua.
local ns = require "needlesim"
return ns.scenario {
    name = "loaded mesh",
    tissue = ns.tissue.file {
        path = "mesh.msh",
        regions = { [1] = ns.materials.fat, [2] = ns.materials.bone },
        names = { [1] = "fat", [2] = "ball" },
        fixed = { 2 },
    },
}
