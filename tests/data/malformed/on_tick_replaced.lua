-- the script replaces on_tick with a number: "attempt to call a number value", no file or line
local sc
sc = require("base").scenario(function() sc.on_tick = 42 end)
sc.on_tick = function(sim) end
return sc
