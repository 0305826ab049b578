-- reads --set label=... (any string): the command-line cases give it odd values
local ns = require "needlesim"
local label = ns.param("label", "x")
return require("short")
