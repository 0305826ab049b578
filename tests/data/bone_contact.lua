-- A needle aimed at bone (issue 32): a gel block with a fixed bone slab across the needle's
-- path 2 cm in. The tip stops at the slab's surface (bone is not cut), the insertion stalls,
-- the report records a `bone_contact` event, and the script withdraws the needle.
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.005
local block = ns.shape.box { center = { 0, 0, 0.02 }, size = { 6 * h, 6 * h, 8 * h } }
local slab = ns.shape.box { center = { 0, 0, 0.03 }, size = { 6 * h, 6 * h, 2 * h } }

return ns.scenario {
    name = "bone contact",
    dt = 0.01,
    tissue = ns.tissue.shapes {
        resolution = h,
        bounds = { { -3 * h, -3 * h, 0 }, { 3 * h, 3 * h, 8 * h } },
        regions = {
            { name = "gel", shape = block, material = ns.materials.gel },
            { name = "bone", shape = slab, material = ns.materials.bone, fixed = true },
        },
    },
    needle = ns.needle { kind = "stiff" },
    entry = { point = { 0, 0, 0 }, direction = { 0, 0, 1 } },
    targets = { { name = "beyond", at = { 0, 0, 0.038 }, tolerance = 2e-3 } },
    -- What a script sees: sim.bone_contact while the tip rests on the bone, and the event.
    on_tick = function(sim)
        if sim.bone_contact and (#sim.events ~= 1 or sim.events[1].type ~= "bone_contact"
                or sim.events[1].region ~= "bone") then
            error("sim.bone_contact without its event in sim.events")
        end
    end,
    script = function()
        -- Aimed past the bone's surface at 2.5 cm: the insertion ends at the bone (false).
        if act.insert { speed = 0.02, depth = 0.035 } then
            error("the needle went through the bone")
        end
        act.wait { time = 0.05 }
        act.retract { speed = 0.02 }
    end,
}
