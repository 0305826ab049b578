-- a result past 2^31 bytes, refused before allocating
local s = string.rep("x", 1e9, "yy")
return require("base").scenario()
