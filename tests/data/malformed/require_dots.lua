-- a module name with ".."
require "a..b"
return require("base").scenario()
