local sc = require("base").scenario()
sc.targets[1].tolerance = 0
return sc
