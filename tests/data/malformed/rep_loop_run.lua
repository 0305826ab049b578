-- The same during the run, which has an instruction budget but no wall clock: it never ends,
-- and a SIGTERM waits for the next count hook, minutes away (issue 32: hung, SIGTERM ignored)
return require("base").scenario(function()
    while true do local s = string.rep("x", 4e8) end
end)
