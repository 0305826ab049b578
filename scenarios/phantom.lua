-- Gel phantom (the paper's §4 validation): a bevel-tip needle is pushed by a robot into a
-- 27.1 x 26.5 x 3.9 cm gelatin block, and fiducial markers on its top surface are tracked.
--
-- We model only the part of the block the needle can reach: a 13 x 7.8 x 3.9 cm slab around
-- the insertion path, full thickness. The needle enters the x = 0 face at mid-width and
-- mid-depth and travels along +x. The slab's other cut faces (x = 13 cm, y = +-3.9 cm) stand
-- where the rest of the gel continues, and its bottom rests on the container: those faces are
-- held (fixed_faces), a simple stand-in for the surrounding gel. The top face, where the
-- markers are, and the entry face stay free.
--
-- What it teaches: ns.tissue.box, origin, fixed_faces, and choosing the resolution. The box
-- is sized in whole multiples of the resolution (10 x 6 x 3 lattice cells of 13 mm), so every
-- face lies on a lattice plane and stays flat with sharp edges; with another size the mesher
-- rounds the box's edges on its max faces (see docs/scenarios.md).
--
-- The paper's phantom mesh had 2,280 tets and 672 nodes; this one is of the same size
-- (`needlesim check scenarios/phantom.lua`).
local ns = require "needlesim"

local h = 0.013 -- resolution [m]

return ns.scenario {
    name = "gel phantom",
    description = "gelatin slab around the insertion path (Chentanez et al. 2009, §4)",
    tissue = ns.tissue.box {
        size = { 10 * h, 6 * h, 3 * h }, -- 13 x 7.8 x 3.9 cm
        origin = { 0, -3 * h, 0 }, -- the needle path is the x axis at y = 0, z = 1.95 cm
        resolution = h,
        material = ns.materials.gel, -- a stand-in: see scripts/needlesim/materials.lua
        fixed_faces = { "xmax", "ymin", "ymax", "zmin" },
    },
}
