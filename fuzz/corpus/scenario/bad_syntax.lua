local ns = require "needlesim"
return ns.scenario {
    name = "bad syntax",
    tissue = ns.tissue.box { size = { 0.02, 0.02, 0.02 } resolution = 0.004 },
}
