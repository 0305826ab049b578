-- Loads a mesh written by Gmsh (two unit boxes, physical volumes 1 "fat" and 3 "muscle", and a
-- physical surface 7 that is not a volume and is ignored). Tags need not be consecutive.
local ns = require "needlesim"
return ns.scenario {
    name = "gmsh two boxes",
    tissue = ns.tissue.file {
        path = "mesh_gmsh_two_boxes41.msh",
        regions = { [1] = ns.materials.fat, [3] = ns.materials.muscle },
        names = { [3] = "muscle block" },
        fixed = { 3 },
    },
}
