local ns = require "needlesim"
-- tests/test_malformed.sh makes fifo.msh a FIFO in its scratch folder and runs from there
return ns.scenario { name = "fifo", tissue = ns.tissue.file { path = "fifo.msh",
    regions = { ns.materials.gel }, fixed = { 1 } } }
