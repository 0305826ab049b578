-- Gel phantom, single bend (the paper's §4 validation): a bevel-tip needle is pushed by a robot
-- 10 cm into a 27.1 x 26.5 x 3.9 cm gelatin block with no twist, so it bends one way, and
-- fiducial markers on the block's top surface are tracked. phantom_double_bend.lua is the same
-- run with a 180 degree twist at half depth.
--
-- We model only the part of the block the needle can reach: a 13 x 7.8 x 3.9 cm slab around
-- the insertion path, full thickness. The needle enters the x = 0 face at mid-width and
-- mid-depth and travels along +x. The slab's other cut faces (x = 13 cm, y = +-3.9 cm) stand
-- where the rest of the gel continues, and its bottom rests on the container: those faces are
-- held (fixed_faces), a simple stand-in for the surrounding gel. The top face, where the
-- markers are, and the entry face stay free.
--
-- What it teaches: ns.tissue.box, origin, fixed_faces, choosing the resolution, markers, and a
-- flexible needle's bevel steering it (compare trajectory.csv with the double bend's). The box
-- is sized in whole multiples of the resolution (10 x 6 x 3 lattice cells of 13 mm), so every
-- face lies on a lattice plane and stays flat with sharp edges; with another size the mesher
-- rounds the box's edges on its max faces (see docs/scenarios.md).
--
-- The paper's phantom mesh had 2,280 tets and 672 nodes; this one is of the same size
-- (`needlesim check scenarios/phantom_single_bend.lua`).
local ns = require "needlesim"
local act = require "needlesim.actions"

local h = 0.013 -- the lattice of the block's size and the entry [m]
-- The mesh resolution is h / refine (refine 1: 13 mm, the paper's mesh size; 2: 6.5 mm; ...):
-- `--set tissue.refine=2` refines the mesh at the same geometry (tools/speed_accuracy.py).
local refine = ns.param("tissue.refine", 1)

-- Fiducials on the top face (z = 3.9 cm), 1 cm either side of the needle's plane, every 2 cm.
local markers = {}
for i = 1, 5 do
    markers[#markers + 1] = { name = "top" .. i .. "L", at = { 0.02 * i, 0.01, 3 * h } }
    markers[#markers + 1] = { name = "top" .. i .. "R", at = { 0.02 * i, -0.01, 3 * h } }
end

return ns.scenario {
    name = "gel phantom, single bend",
    description = "gelatin slab around the insertion path (Chentanez et al. 2009, §4)",
    tissue = ns.tissue.box {
        size = { 10 * h, 6 * h, 3 * h }, -- 13 x 7.8 x 3.9 cm
        origin = { 0, -3 * h, 0 }, -- the needle path is the x axis at y = 0, z = 1.95 cm
        resolution = h / refine,
        material = ns.materials.gel, -- a stand-in: see scripts/needlesim/materials.lua
        fixed_faces = { "xmax", "ymin", "ymax", "zmin" },
    },
    dt = ns.param("dt", 0.01),
    -- The coupled solve's tolerances and the lazy-Jacobian threshold (the engine's defaults
    -- unless set: docs/performance.md measures what they cost and give).
    solver = {
        tolerance = ns.param("solver.tolerance", 1e-8),
        -- checked a hundred times looser, as the paper does (1e-3 and 1e-5)
        check_tolerance = math.min(0.5, 100 * ns.param("solver.tolerance", 1e-8)),
        lazy_threshold = ns.param("solver.lazy_threshold", 1e-2),
    },
    -- The phantom needle: 0.83 mm nitinol, bevel tip (the paper's §4).
    needle = ns.needle { kind = "flexible", bevel_deg = ns.param("needle.bevel_deg", 30) },
    -- At z = 2 h = 2.6 cm, one lattice spacing below the top markers.
    -- The bevel faces sideways (+y): the needle bends in the horizontal plane, as in the paper.
    entry = { point = { 0, 0, 2 * h }, direction = { 1, 0, 0 }, bevel_toward = { 0, 1, 0 } },
    markers = markers,
    -- The bend is horizontal: seen from above, cut level with the needle.
    camera = { views = { "top" } },
    script = function()
        act.insert { speed = 0.01, depth = 0.10 } -- 10 cm at 10 mm/s, no twist
        act.wait { time = 0.5 }
    end,
}
