local ns = require "needlesim"
return ns.scenario {
    name = "an accuracy no measured setting reaches",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004,
        material = ns.materials.gel },
    accuracy = { tip = 1e-9, front = "phantom" },
}
