-- a format width Lua refuses
local s = string.format("%99999d", 1)
return require("base").scenario()
