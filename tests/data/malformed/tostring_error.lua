-- an error value whose __tostring errors
error(setmetatable({}, { __tostring = function() error("inner") end }))
