local ns = require "needlesim"
return ns.scenario {
    name = "a misspelt camera field",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    camera = { fps = 30, tet_edge = false },
}
