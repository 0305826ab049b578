local sc = require("base").scenario()
sc.entry.point = { "a", {}, nil }
return sc
