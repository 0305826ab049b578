local sc = require("base").scenario()
sc.dt = 0 / 0
return sc
