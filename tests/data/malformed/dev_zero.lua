local ns = require "needlesim"
return ns.scenario { name = "zero", tissue = ns.tissue.file { path = "/dev/zero",
    regions = { ns.materials.gel }, fixed = { 1 } } }
