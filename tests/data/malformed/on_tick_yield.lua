-- on_tick yields: "attempt to yield from outside a coroutine", without file or line
local sc = require("base").scenario()
sc.on_tick = function(sim) coroutine.yield() end
return sc
