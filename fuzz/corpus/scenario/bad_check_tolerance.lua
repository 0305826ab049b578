local ns = require "needlesim"
return ns.scenario {
    name = "a check tolerance below the default tolerance",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    solver = { check_tolerance = 1e-9 },
}
