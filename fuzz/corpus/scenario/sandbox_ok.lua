-- What the sandbox allows and refuses; any failed assert makes `check` exit 1.
local ns = require "needlesim"
local helper = require "helper_block" -- a plain name: helper_block.lua beside this file
assert(require "helper_block" == helper, "modules are cached")
assert(require "needlesim.materials" == ns.materials, "ns.materials is needlesim.materials")

-- Libraries that are not there, and functions removed from those that are.
for _, name in ipairs { "io", "os", "package", "debug", "dofile", "loadfile" } do
    assert(_G[name] == nil, name .. " must not exist")
end
assert(string.dump == nil, "string.dump must not exist")
for _, name in ipairs { "io", "os", "package", "debug", "../x", "/etc/passwd", "a/b" } do
    assert(not pcall(require, name), "require '" .. name .. "' must fail")
end

-- load: text only.
assert(load("return 6 * 7")() == 42)
local f, msg = load("\27Lua binary")
assert(f == nil and msg:find("binary"), "binary chunks must be refused")

-- Deterministic random numbers.
local r1 = math.random(1 << 30)
math.randomseed(0x6e73)
assert(math.random(1 << 30) == r1, "math.random starts from the fixed seed")

print("sandbox_ok: printed to stderr")
return ns.scenario { name = "sandbox ok", tissue = helper.block(0.004) }
