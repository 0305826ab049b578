-- mesh.msh has physical tags 1 and 2; tag 2 has no material here.
local ns = require "needlesim"
return ns.scenario {
    name = "missing tag",
    tissue = ns.tissue.file { path = "mesh.msh", regions = { [1] = ns.materials.fat } },
}
