local sc = require("base").scenario()
sc.camera = { frame_every = 0 } -- set after the constructor checked the camera
return sc
