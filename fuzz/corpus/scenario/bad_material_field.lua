local ns = require "needlesim"
local liver = ns.material {
    name = "liver", yougns = 10e3, poisson = 0.45, density = 1060,
}
return ns.scenario {
    name = "misspelt material field",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 }, resolution = 0.004, material = liver },
}
