-- backtracking in the C pattern matcher, which the instruction hook never sees
local s = string.rep("a", 60000)
local found = string.find(s, ".-.-.-.-b")
return require("base").scenario()
