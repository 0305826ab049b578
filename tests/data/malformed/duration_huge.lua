local sc = require("base").scenario()
sc.duration = 1e9
return sc
