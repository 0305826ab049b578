local sc = require("base").scenario()
-- an erroring __index on a table the engine reads, and the field it would supply removed
setmetatable(sc.targets[1], { __index = function() error("boom") end })
sc.targets[1].tolerance = nil
return sc
