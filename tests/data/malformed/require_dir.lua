-- require of a module that is a folder (the test makes moddir.lua a folder)
require "moddir"
return require("base").scenario()
