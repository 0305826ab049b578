local ns = require "needlesim"
return ns.scenario {
    name = "function shape without bounds",
    tissue = ns.tissue.shapes {
        resolution = 0.004,
        regions = {
            { name = "ball", material = ns.materials.gel,
                shape = function(x, y, z) return math.sqrt(x * x + y * y + z * z) - 0.01 end },
        },
    },
}
