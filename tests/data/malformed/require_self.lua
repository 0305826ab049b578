-- a module that requires itself
require "require_self"
return require("base").scenario()
