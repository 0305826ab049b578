-- a __tostring that calls tostring on itself: "C stack overflow", without file or line
local t = setmetatable({}, { __tostring = function(x) return tostring(x) end })
print(t)
return require("base").scenario()
