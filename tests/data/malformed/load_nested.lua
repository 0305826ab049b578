-- load() of deeply nested parentheses: the parser's C stack limit
local s = string.rep("(", 100000) .. "1" .. string.rep(")", 100000)
assert(load("return " .. s))()
return require("base").scenario()
