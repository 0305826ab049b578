-- more memory than a scenario may hold
local t = {}
for i = 1, 100 do t[i] = string.rep("x", 1 << 26) .. i end
return require("base").scenario()
