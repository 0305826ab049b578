local act = require "needlesim.actions"
return require("base").scenario(function() act.twist { angle = 1e12 } end)
