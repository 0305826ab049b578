local sc = require("base").scenario()
sc.needle.steering = "sideways"
return sc
