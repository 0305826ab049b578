-- the string metatable's __index replaced: the needlesim library uses s:byte etc.
getmetatable("").__index = function(s, k) error("hijacked " .. k) end
return require("base").scenario()
