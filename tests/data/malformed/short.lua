-- base.lua for 5 steps: a run that succeeds, for the command-line and control-log cases
local sc = require("base").scenario()
sc.duration = 0.05
return sc
