local ns = require "needlesim"
local io = require "io"
return io.open("/etc/passwd")
