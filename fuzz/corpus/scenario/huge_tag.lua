-- A legal mesh whose one tet has physical tag 2^31 - 1: regions are found by sorting the tags
-- present, not by an array indexed by tag (which would take gigabytes).
local ns = require "needlesim"
return ns.scenario {
  name = "huge tag",
  tissue = ns.tissue.file { path = "huge_tag.msh", regions = { [2147483647] = ns.materials.gel } },
}
