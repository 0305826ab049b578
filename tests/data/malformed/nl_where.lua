-- the constructor's `where`, which every later message starts with, rewritten with a newline
local sc = require("base").scenario()
sc.where = "first\nsecond"
sc.dt = 0
return sc
