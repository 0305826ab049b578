local sc = require("base").scenario(function() coroutine.yield() end)
sc.duration = 0.05
sc.on_tick = function(sim) sim.control.next_needle = { point = { 0, 0, 0 }, direction = { "x", 0, 1 } } end
return sc
