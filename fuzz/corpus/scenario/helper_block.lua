-- A plain module beside the scenarios that `require "helper_block"` loads (sandbox_ok.lua).
local ns = require "needlesim"
local M = {}

function M.block(resolution)
    return ns.tissue.box { size = { 0.02, 0.02, 0.012 }, resolution = resolution,
        material = ns.materials.gel }
end

return M
