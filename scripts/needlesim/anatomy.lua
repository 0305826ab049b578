-- needlesim.anatomy: ready-made synthetic anatomy for scenarios (require "needlesim.anatomy").
--
-- anatomy.pelvis{...}: the male pelvis of the brachytherapy scenarios, built from textbook
-- dimensions, in a patient frame:
--   x: patient left (+) / right (-); y: anterior (+, towards the pubis) / posterior (-, rectum);
--   z: depth from the perineal skin (z = 0) towards the bladder (+). Metres throughout.
-- Only the block the needles can reach is modelled (7.2 x 9.2 x 9.8 cm), the paper's rule of
-- "model no more than a scene needs"; the paper's mesh of a whole pelvis had 13,375 tets.
--
-- Dimensions (adult male, textbook values):
--   prostate 4 cm wide x 3 cm antero-posterior x 3 cm long (about 19 cc), apex ~3.5 cm deep from
--     the perineal skin (the usual transperineal needle path is 5-7 cm long);
--   prostatic urethra through its centre, slightly anterior, continuing into the bladder neck;
--     modelled with its surrounding sphincter tissue as a 5 mm radius tube;
--   bladder base above the prostate base; rectum behind the prostate (wall and lumen in one
--     region, the wall being thinner than the mesh spacing);
--   perineal muscle (urogenital diaphragm / perineal body) between the skin and the apex;
--   pubic arch: the inferior pubic rami meeting at the symphysis, anterior to the prostate,
--     held fixed (bone).
-- The capsule of the prostate (0.5 mm) and the skin (1 mm) are far thinner than an element:
-- as in the paper (§3.3) they are membranes that raise the cutting force where the needle
-- crosses the region's surface (the materials' `membrane` field), not separate regions.
--
-- Fields (all optional): prostate_radii = {rx, ry, rz} [m] (default {0.020, 0.015, 0.015}; a
-- larger gland for a full implant), arch_drop [m] (default 0: the pubic arch lowered towards the
-- prostate by this much, a narrow arch whose rami stand in the way of the anterior-lateral
-- needles: pubic arch interference), resolution [m] (default 8.8e-3). Returns
-- {tissue = ns.tissue.shapes{...}, shapes = {block, prostate, urethra, bladder, rectum,
-- perineum, pubic_arch}}.
local ns = require "needlesim"
local M = ns.materials
local shape = ns.shape

local anatomy = {}

local PELVIS_FIELDS = { prostate_radii = true, arch_drop = true, resolution = true }

function anatomy.pelvis(t)
    t = t or {}
    if type(t) ~= "table" then
        error("anatomy.pelvis: expected a table of fields {prostate_radii, arch_drop, resolution}",
            2)
    end
    for k in pairs(t) do
        if not PELVIS_FIELDS[k] then
            error(string.format("anatomy.pelvis: unknown field '%s' (known: prostate_radii, "
                .. "arch_drop, resolution)", tostring(k)), 2)
        end
    end
    local r = t.prostate_radii or { 0.020, 0.015, 0.015 }
    if type(r) ~= "table" or #r ~= 3 then
        error("anatomy.pelvis: prostate_radii must be {rx, ry, rz} [m]", 2)
    end
    for i = 1, 3 do
        if type(r[i]) ~= "number" or not (r[i] >= 0.010 and r[i] <= 0.030) then
            error("anatomy.pelvis: prostate_radii must be three numbers in [0.010, 0.030] [m]", 2)
        end
    end
    local drop = t.arch_drop or 0
    if type(drop) ~= "number" or not (drop >= 0 and drop <= 0.012) then
        error("anatomy.pelvis: arch_drop must be a number in [0, 0.012] [m]", 2)
    end
    local res = t.resolution or 8.8e-3
    if type(res) ~= "number" or not (res >= 3e-3 and res <= 0.02) then
        error("anatomy.pelvis: resolution must be a number in [3e-3, 0.02] [m]", 2)
    end

    -- The perineal fat carries the skin as a membrane on its surface (1 mm, §3.3): the needle
    -- meets the skin's puncture force where it enters. Puncture force: estimate (materials.lua).
    local perineal_fat = ns.material {
        base = M.fat,
        name = "perineal fat",
        membrane = { thickness = 1e-3, cut_force = 2.0 },
    }
    -- The modelled block: from the perineal skin (z = 0) to just past the bladder base. Every
    -- organ stays at least one lattice cell inside it, so the skin surface meets no organ
    -- (docs/mesher.md: interfaces closer than a cell to the outer boundary bend towards it).
    local s = {}
    s.block = shape.box { center = { 0, -0.002, 0.049 }, size = { 0.072, 0.092, 0.098 } }
    s.prostate = shape.ellipsoid { center = { 0, 0, 0.050 }, radii = { r[1], r[2], r[3] } }
    -- Prostatic urethra with its sphincter (the usual 5 mm planning margin), apex to bladder neck.
    s.urethra = shape.capsule { a = { 0, 0.004, 0.026 }, b = { 0, 0.004, 0.076 }, radius = 0.005 }
    s.bladder = shape.ellipsoid { center = { 0, 0.006, 0.079 }, radii = { 0.026, 0.022, 0.012 } }
    s.rectum = shape.capsule { a = { 0, -0.029, 0.014 }, b = { 0, -0.029, 0.072 }, radius = 0.010 }
    s.perineum = shape.box { center = { 0, 0.004, 0.020 }, size = { 0.044, 0.030, 0.010 } }
    s.pubic_arch = shape.union(
      shape.capsule { a = { -0.022, 0.020 - drop, 0.024 }, b = { 0, 0.030 - drop, 0.044 },
        radius = 0.006 },
      shape.capsule { a = { 0.022, 0.020 - drop, 0.024 }, b = { 0, 0.030 - drop, 0.044 },
        radius = 0.006 })
    local tissue = ns.tissue.shapes {
      resolution = res,
      -- Later regions override earlier ones where they overlap.
      regions = {
        { name = "fat", shape = s.block, material = perineal_fat },
        { name = "perineum", shape = s.perineum, material = M.muscle },
        { name = "rectum", shape = s.rectum, material = M.rectum },
        { name = "bladder", shape = s.bladder, material = M.bladder },
        { name = "prostate", shape = s.prostate, material = M.prostate },
        { name = "urethra", shape = s.urethra, material = M.urethra },
        { name = "pubic_arch", shape = s.pubic_arch, material = M.bone, fixed = true },
      },
    }
    return { tissue = tissue, shapes = s }
end

return anatomy
