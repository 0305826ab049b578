-- many small allocations at the memory limit: each would otherwise cost a full collection
local t = {} for i = 1, 1e8 do t[i] = string.rep("x", 100) .. i end
