local sc = require("base").scenario(function() end)
sc.duration = 0.1
-- the control written directly, around the actions
sc.on_tick = function(sim) sim.control.v_insert = 3e9 end
return sc
