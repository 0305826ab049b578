-- table.sort with a comparator that always says "less"
local t = {} for i = 1, 1000 do t[i] = i end table.sort(t, function(a, b) return true end)
return require("base").scenario()
