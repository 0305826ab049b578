-- a string the scenario controls, with a newline, echoed into the one-line message
local sc = require("base").scenario()
sc.tissue.material.model = "rubber\nsecond line"
return sc
