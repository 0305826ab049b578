local ns = require "needlesim"
return ns.scenario { name = string.rep("n", 1000), tissue = ns.tissue.box { size = {0.02,0.02,0.02}, resolution = 5e-3, material = ns.materials.gel, fixed_faces = {"zmax"} } }
