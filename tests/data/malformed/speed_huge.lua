local act = require "needlesim.actions"
return require("base").scenario(function() act.insert { speed = 1e9, depth = 0.01 } end)
