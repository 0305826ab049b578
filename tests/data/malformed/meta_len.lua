local sc = require("base").scenario()
-- a __len that returns 1.5 (luaL_len would raise outside any protected call), and dt broken
setmetatable(sc.targets, { __len = function() return 1.5 end })
sc.dt = 0
return sc
