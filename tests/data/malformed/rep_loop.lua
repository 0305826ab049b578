-- C work the instruction budget never sees: string.rep builds 400 MB in a handful of
-- instructions, so the count hook (every 10,000 instructions) and its 60 s wall clock come
-- round only after minutes (issue 32: hung past 60 s)
for _ = 1, 1e6 do local s = string.rep("x", 4e8) end
return require("base").scenario()
