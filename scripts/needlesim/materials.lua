-- Ready-made tissue materials: ns.materials.<name> (or require "needlesim.materials").
--
-- SI units: youngs [Pa], poisson [-], density [kg/m^3], damping [Pa s], friction [N/m]
-- (needle-tissue friction per unit length of needle in the tissue, paper §3.3 f_perlen),
-- cut_force [N] (extra force at a cutting tip, §3.3 f_cut), membrane (a capsule at the
-- region's surface that takes a larger force to puncture, §3.3 "capsule puncture").
--
-- Where a value comes from a measurement the source is beside it. Many are not measured
-- here and say "estimate": treat them as plausible starting points, to be tuned against
-- experiments (the paper tuned damping and needle parameters by hand, §4). Published soft-
-- tissue moduli spread widely with loading rate, precompression and method; all of these are
-- small-strain, low-rate values.
--
-- Poisson's ratio: soft tissue is nearly incompressible (nu ~ 0.45-0.5). We use 0.45 for
-- all soft tissue: linear tetrahedra lock (become artificially stiff) as nu -> 0.5, and 0.45
-- is a common compromise in needle-insertion FEM. Estimate.
--
-- Density: ICRU Report 44 (1989), "Tissue substitutes in radiation dosimetry and
-- measurement", body-tissue compositions: adipose ~950, skeletal muscle ~1050, skin ~1090,
-- cortical bone ~1920 kg/m^3; other soft tissue taken as ~1040 (estimate).

local ns = require "needlesim"

local M = {}

-- Prostate gland. Krouskop et al. 1998, "Elastic moduli of breast and prostate tissues under
-- compression", Ultrasonic Imaging 20:260-274: normal prostate ~55-62 kPa at low
-- precompression (BPH softer, cancer stiffer). Friction and cutting force: estimates chosen
-- to give total axial forces of a few newtons over a few centimetres, the order of the in
-- vivo brachytherapy needle forces reported by Podder et al. 2006 (IEEE EMBS, "In vivo
-- measurement of surgical needle intervention parameters: a pilot study"). The capsule (§3.3,
-- capsule puncture observed by Simone & Okamura 2002, ICRA, "Modeling of needle insertion
-- forces for robot-assisted percutaneous therapy"): thickness and puncture force are
-- estimates.
M.prostate = ns.material {
    name = "prostate",
    youngs = 60e3, -- Krouskop 1998 (normal tissue ~55-62 kPa)
    poisson = 0.45, -- estimate (see top)
    density = 1040, -- estimate (soft tissue)
    damping = 10, -- estimate
    friction = 80, -- estimate
    cut_force = 1.0, -- estimate
    membrane = { thickness = 0.5e-3, cut_force = 2.5 }, -- estimate
}

-- Fat (adipose). Krouskop et al. 1998: breast fat ~18-22 kPa at low precompression.
M.fat = ns.material {
    name = "fat",
    youngs = 20e3, -- Krouskop 1998 (~18-22 kPa)
    poisson = 0.45, -- estimate
    density = 950, -- ICRU 44 (adipose)
    damping = 5, -- estimate
    friction = 30, -- estimate
    cut_force = 0.3, -- estimate
}

-- Skin (dermis). In vivo moduli in the literature span roughly 10 kPa to several MPa with
-- method and strain; 100 kPa is a small-strain, indentation-scale value. Estimate.
-- The high cutting force models the resistance of skin puncture. Estimate.
M.skin = ns.material {
    name = "skin",
    youngs = 100e3, -- estimate (literature spans ~10 kPa-MPa)
    poisson = 0.45, -- estimate
    density = 1090, -- ICRU 44 (skin)
    damping = 10, -- estimate
    friction = 100, -- estimate
    cut_force = 2.0, -- estimate
}

-- Skeletal muscle, relaxed, across the fibres (the perineum in a brachytherapy model).
-- Reported small-strain moduli of relaxed muscle are of the order of 10-100 kPa. Estimate.
M.muscle = ns.material {
    name = "muscle",
    youngs = 50e3, -- estimate
    poisson = 0.45, -- estimate
    density = 1050, -- ICRU 44 (skeletal muscle)
    damping = 10, -- estimate
    friction = 80, -- estimate
    cut_force = 1.0, -- estimate
}
M.perineum = ns.material { base = M.muscle, name = "perineum" }

-- Bladder wall. Estimate (moduli of the order of 100 kPa are reported for the wall at
-- moderate fill; it stiffens as it fills).
M.bladder = ns.material {
    name = "bladder",
    youngs = 100e3, -- estimate
    poisson = 0.45, -- estimate
    density = 1040, -- estimate (soft tissue)
    damping = 10, -- estimate
    friction = 60, -- estimate
    cut_force = 1.0, -- estimate
}

-- Rectal wall. Estimate.
M.rectum = ns.material {
    name = "rectum",
    youngs = 80e3, -- estimate
    poisson = 0.45, -- estimate
    density = 1040, -- estimate (soft tissue)
    damping = 10, -- estimate
    friction = 60, -- estimate
    cut_force = 1.0, -- estimate
}

-- Urethra (with its surrounding tissue). Estimate.
M.urethra = ns.material {
    name = "urethra",
    youngs = 60e3, -- estimate
    poisson = 0.45, -- estimate
    density = 1040, -- estimate (soft tissue)
    damping = 10, -- estimate
    friction = 60, -- estimate
    cut_force = 0.8, -- estimate
}

-- Bone (cortical). Rho, Ashman & Turner 1993, "Young's modulus of trabecular and cortical
-- bone material: ultrasonic and microtensile measurements", J. Biomech. 26:111-119: cortical
-- bone ~ 15-20 GPa. Regions of bone are normally fixed (the paper holds the pelvis, §4), so
-- its stiffness rarely enters a solve. A needle does not cut bone: a very large cut_force.
M.bone = ns.material {
    name = "bone",
    youngs = 15e9, -- Rho et al. 1993 (cortical bone, order of magnitude)
    poisson = 0.3, -- typical for cortical bone
    density = 1920, -- ICRU 44 (cortical bone)
    damping = 0,
    friction = 0,
    cut_force = 1e4, -- effectively impenetrable
}

-- Gelatin phantom. The paper's phantom (§4, Webster et al.'s steerable-needle experiments)
-- was characterised by compression tests whose values the paper does not print; this is a
-- STAND-IN: gelatin phantoms of the usual concentrations measure ~10-35 kPa. Replace it with
-- your own phantom's measured E and nu. Friction, cutting force and damping: estimates.
M.gel = ns.material {
    name = "gel",
    youngs = 20e3, -- stand-in (typical gelatin phantom ~10-35 kPa)
    poisson = 0.45, -- estimate (see top)
    density = 1040, -- estimate (water-based gel)
    damping = 5, -- estimate
    friction = 30, -- estimate
    cut_force = 0.3, -- estimate
}

return M
