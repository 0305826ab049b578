-- an error value whose __tostring gives a message without a position (the first line of it
-- is all that is shown: "multi")
error(setmetatable({}, { __tostring = function() return "multi\nline" end }))
