-- needlesim: the scenario API (docs/scenarios.md is the reference).
--
--   local ns = require "needlesim"
--   return ns.scenario{ name = "...", tissue = ns.tissue.box{ ... } }
--
-- Every constructor checks its table of fields and returns a new, tagged table that the
-- engine (engine/scenario.c) reads back. Typos must not pass silently: an unknown field, a
-- missing one or a value out of range is an error that names the scenario's file:line (where
-- the constructor was called), the constructor and the field, e.g.
--   scenarios/x.lua:7: ns.tissue.box: resolution must be a number > 0 (got -0.004)
-- Each table also keeps that place as `where`, so the engine can name it in errors it finds
-- later (a mesh file that does not open, a shape function that fails while meshing).
--
-- Units are SI throughout: metres, kilograms, seconds, pascals, newtons.

local where_of = __ns_where -- provided by the engine: "file:line" `level` frames up
local fmt, concat, sort = string.format, table.concat, table.sort
local huge, type, pairs, ipairs, select = math.huge, type, pairs, ipairs, select
local tostring, setmetatable, getmetatable, rawget, error = tostring, setmetatable,
    getmetatable, rawget, error

local ns = {}

-- Kinds ------------------------------------------------------------------------------------
-- A table's kind lives in its metatable (`__ns_kind`), where the engine looks for it.

local function make_kind(kind, label)
    return {
        __ns_kind = kind,
        __name = "ns." .. kind,
        __tostring = function(t)
            return fmt("%s (%s)", label(t), rawget(t, "where") or "?")
        end,
    }
end

local SHAPE = make_kind("shape", function(t) return "ns.shape." .. tostring(t.type) end)
local MATERIAL = make_kind("material", function(t) return fmt("ns.material '%s'", t.name) end)
local TISSUE = make_kind("tissue", function(t) return "ns.tissue." .. tostring(t.type) end)
local SCENARIO = make_kind("scenario", function(t) return fmt("ns.scenario '%s'", t.name) end)
local NEEDLE = make_kind("needle", function(t) return fmt("ns.needle '%s'", t.kind) end)

local function kind_of(v)
    if type(v) ~= "table" then
        return nil
    end
    local mt = getmetatable(v)
    return type(mt) == "table" and rawget(mt, "__ns_kind") or nil
end

--- The kind of a needlesim table ("shape", "material", "tissue", "scenario"), or nil.
function ns.kind(v)
    return kind_of(v)
end

-- Messages ---------------------------------------------------------------------------------

local function is_finite(x)
    return type(x) == "number" and x == x and x > -huge and x < huge
end

-- A short, one-line description of a value for "(got ...)".
local function describe(v)
    local t = type(v)
    if t == "number" then
        if v ~= v then
            return "nan"
        end
        return tostring(v)
    elseif t == "string" then
        local s = v:gsub("%c", "?")
        if #s > 40 then
            s = s:sub(1, 37) .. "..."
        end
        return "'" .. s .. "'"
    elseif t == "table" then
        local k = kind_of(v)
        if k then
            return k == "shape" and ("ns.shape." .. tostring(v.type)) or ("a " .. k)
        end
        local n = #v
        if n >= 1 and n <= 9 then
            local parts = {}
            for i = 1, n do
                local x = v[i]
                if type(x) == "number" or type(x) == "string" then
                    parts[i] = describe(x)
                else
                    parts[i] = type(x)
                end
            end
            return "{" .. concat(parts, ", ") .. "}"
        end
        return "a table"
    elseif t == "nil" or t == "boolean" then
        return tostring(v)
    end
    return "a " .. t
end

local function raise(where, ctor, msg)
    error(where .. ": " .. ctor .. ": " .. msg, 0)
end

-- Edit distance, for "did you mean ...?" on a misspelt field.
local function distance(a, b)
    local prev = {}
    for j = 0, #b do
        prev[j] = j
    end
    for i = 1, #a do
        local cur = { [0] = i }
        for j = 1, #b do
            local cost = a:sub(i, i) == b:sub(j, j) and 0 or 1
            cur[j] = math.min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + cost)
        end
        prev = cur
    end
    return prev[#b]
end

local function suggestion(name, known)
    local best, best_d = nil, huge
    for _, k in ipairs(known) do
        local d = distance(name:lower(), k:lower())
        if d < best_d then
            best, best_d = k, d
        end
    end
    if best and best_d <= math.max(2, #name // 3) then
        return fmt("; did you mean '%s'?", best)
    end
    return ""
end

-- Argument tables --------------------------------------------------------------------------
-- args(t, ctor, where, known) checks that t is a plain table whose keys are all in `known`
-- and returns a reader with typed accessors; each raises at `where` with `ctor` in front.

local Args = {}
Args.__index = Args

local OPTIONAL = {} -- a default that means "absent is fine, give nil"

local function key_order(a, b)
    local ta, tb = type(a), type(b)
    if ta ~= tb then
        return ta < tb
    end
    if ta == "string" or ta == "number" then
        return a < b
    end
    return tostring(a) < tostring(b)
end

local function args(t, ctor, where, known)
    if type(t) ~= "table" or kind_of(t) then
        raise(where, ctor, fmt("expected a table of fields {%s} (got %s)", concat(known, ", "),
            describe(t)))
    end
    local set = {}
    for _, k in ipairs(known) do
        set[k] = true
    end
    local unknown = {}
    for k in pairs(t) do
        if not set[k] then
            unknown[#unknown + 1] = k
        end
    end
    if #unknown > 0 then
        sort(unknown, key_order) -- deterministic whatever the hash order
        local k = unknown[#unknown] -- strings sort after numbers: name a misspelt field first
        for _, u in ipairs(unknown) do
            if type(u) == "string" then
                k = u
                break
            end
        end
        if type(k) ~= "string" then
            raise(where, ctor, fmt("unexpected positional value [%s] = %s (fields are named: %s)",
                tostring(k), describe(t[k]), concat(known, ", ")))
        end
        local more = ""
        if #unknown > 1 then
            more = fmt(" (and %d more unknown)", #unknown - 1)
        end
        raise(where, ctor, fmt("unknown field '%s'%s (known: %s)%s", k, more,
            concat(known, ", "), suggestion(k, known)))
    end
    return setmetatable({ t = t, ctor = ctor, where = where }, Args)
end

function Args:fail(msg, ...)
    raise(self.where, self.ctor, fmt(msg, ...))
end

function Args:get(k)
    return self.t[k]
end

local function GT0(x) return x > 0 end
local function GE0(x) return x >= 0 end
local function ANY() return true end

-- A number field; `test`/`what` say which numbers are allowed ("> 0").
function Args:number(k, test, what, default)
    local v = self.t[k]
    if v == nil then
        if default == OPTIONAL then
            return nil
        elseif default ~= nil then
            return default
        end
        self:fail("missing required field '%s' (a number %s)", k, what)
    end
    if not is_finite(v) or not test(v) then
        self:fail("%s must be a number %s (got %s)", k, what, describe(v))
    end
    return v
end

-- A list of n finite numbers, each passing `test`; returns a fresh copy.
local function vector(v, n, test)
    if type(v) ~= "table" or kind_of(v) then
        return nil
    end
    local count = 0
    for _ in pairs(v) do
        count = count + 1
    end
    if count ~= n then
        return nil
    end
    local out = {}
    for i = 1, n do
        local x = v[i]
        if not is_finite(x) or not test(x) then
            return nil
        end
        out[i] = x
    end
    return out
end

function Args:vec3(k, test, what, default)
    local v = self.t[k]
    if v == nil then
        if default == OPTIONAL then
            return nil
        elseif default ~= nil then
            return { default[1], default[2], default[3] }
        end
        self:fail("missing required field '%s' ({x, y, z}: 3 numbers%s)", k, what)
    end
    local out = vector(v, 3, test)
    if not out then
        self:fail("%s must be {x, y, z}: 3 numbers%s (got %s)", k, what, describe(v))
    end
    return out
end

function Args:string(k, default)
    local v = self.t[k]
    if v == nil then
        if default == OPTIONAL then
            return nil
        elseif default ~= nil then
            return default
        end
        self:fail("missing required field '%s' (a string)", k)
    end
    if type(v) ~= "string" or v == "" then
        self:fail("%s must be a non-empty string (got %s)", k, describe(v))
    end
    return v
end

-- Names end up in CSV headers (trajectory.csv's marker columns), JSON and log lines: 1 to
-- NS_LIMIT_NAME_LENGTH bytes (sim/ns_limits.h) of printable ASCII, spaces included, without
-- ',', '"' or '\'. The engine checks them again (engine/names.c).
local NAME_MAX = 64
local NAME_RULE = "1 to 64 bytes of printable ASCII without ',', '\"' or '\\' (spaces are fine)"

-- What is wrong with a name, or nil.
local function name_problem(s)
    if #s > NAME_MAX then
        return fmt("it is %d bytes long", #s)
    end
    for i = 1, #s do
        local c = s:byte(i)
        if c < 32 or c > 126 then
            return fmt("byte %d is 0x%02x", i, c)
        elseif c == 44 or c == 34 or c == 92 then
            return fmt("byte %d is '%s'", i, string.char(c))
        end
    end
    return nil
end

-- A name field (see NAME_RULE); `label` names it in messages (default: the field).
function Args:name(k, label, default)
    local v = self:string(k, default)
    if v ~= nil then
        local why = name_problem(v)
        if why then
            self:fail("%s must be %s (got %s: %s)", label or k, NAME_RULE, describe(v), why)
        end
    end
    return v
end

function Args:boolean(k, default)
    local v = self.t[k]
    if v == nil then
        return default
    end
    if type(v) ~= "boolean" then
        self:fail("%s must be true or false (got %s)", k, describe(v))
    end
    return v
end

function Args:choice(k, choices, default)
    local v = self.t[k]
    if v == nil then
        return default
    end
    for _, c in ipairs(choices) do
        if v == c then
            return v
        end
    end
    self:fail("%s must be one of '%s' (got %s)", k, concat(choices, "', '"), describe(v))
end

function Args:func(k)
    local v = self.t[k]
    if v ~= nil and type(v) ~= "function" then
        self:fail("%s must be a function (got %s)", k, describe(v))
    end
    return v
end

local function material_hint(v)
    if type(v) == "string" then
        return fmt("; did you mean ns.materials.%s?", v)
    end
    return ""
end

function Args:material(k)
    local v = self.t[k]
    if v == nil then
        self:fail("missing required field '%s' (ns.material{...} or ns.materials.<name>)", k)
    end
    if kind_of(v) ~= "material" then
        self:fail("%s must be a material, ns.material{...} or ns.materials.<name> (got %s)%s", k,
            describe(v), material_hint(v))
    end
    return v
end

local function is_shape(v)
    return type(v) == "function" or kind_of(v) == "shape"
end

function Args:shape(k)
    local v = self.t[k]
    if v == nil then
        self:fail("missing required field '%s' (ns.shape.* or function(x, y, z))", k)
    end
    if not is_shape(v) then
        self:fail("%s must be a shape, ns.shape.* or function(x, y, z) (got %s)", k, describe(v))
    end
    return v
end

local function new(mt, t)
    return setmetatable(t, mt)
end

-- Materials --------------------------------------------------------------------------------

local MATERIAL_FIELDS = { "name", "youngs", "poisson", "density", "damping", "friction",
    "cut_force", "model", "membrane", "base" }
local MEMBRANE_FIELDS = { "thickness", "cut_force" }

--- ns.material{name, youngs, poisson, density, damping, friction, cut_force, model,
---             membrane = {thickness, cut_force}, base}
-- With `base` (another material) every field not given is taken from it.
function ns.material(t)
    local where = where_of(2)
    local a = args(t, "ns.material", where, MATERIAL_FIELDS)
    local base = t.base
    if base ~= nil and kind_of(base) ~= "material" then
        a:fail("base must be a material (got %s)%s", describe(base), material_hint(base))
    end
    if base then
        -- Read through to the base for fields not given here.
        local merged = {}
        for _, k in ipairs(MATERIAL_FIELDS) do
            if k ~= "base" then
                local v = t[k]
                if v == nil then
                    v = base[k]
                end
                merged[k] = v
            end
        end
        a.t = merged
    end
    local m = {
        name = a:name("name"),
        youngs = a:number("youngs", GT0, "> 0 [Pa]"),
        poisson = a:number("poisson", function(x) return x >= 0 and x < 0.5 end,
            "in [0, 0.5)"),
        density = a:number("density", GT0, "> 0 [kg/m^3]"),
        damping = a:number("damping", GE0, ">= 0 [Pa s]", 0),
        friction = a:number("friction", GE0, ">= 0 [N/m]", 0),
        cut_force = a:number("cut_force", GE0, ">= 0 [N]", 0),
        model = a:choice("model", { "corotational", "neohookean" }, "corotational"),
        where = where,
    }
    local mem = a.t.membrane
    if mem ~= nil then
        local ma = args(mem, "ns.material: membrane", where, MEMBRANE_FIELDS)
        m.membrane = {
            thickness = ma:number("thickness", GT0, "> 0 [m]"),
            cut_force = ma:number("cut_force", GE0, ">= 0 [N]"),
        }
    end
    return new(MATERIAL, m)
end

-- ns.materials is scripts/needlesim/materials.lua, loaded on first use (it requires this
-- module, so it cannot be loaded while this one is).
setmetatable(ns, {
    __index = function(t, k)
        if k == "materials" then
            local m = require "needlesim.materials"
            rawset(t, "materials", m)
            return m
        end
        return nil
    end,
})

-- Shapes -----------------------------------------------------------------------------------
-- Signed distance, negative inside, in metres. A plain Lua function(x, y, z) returning the
-- signed distance is accepted anywhere a shape is.

ns.shape = {}

local function shape(t)
    return new(SHAPE, t)
end

--- ns.shape.sphere{center, radius}
function ns.shape.sphere(t)
    local where = where_of(2)
    local a = args(t, "ns.shape.sphere", where, { "center", "radius" })
    return shape { type = "sphere", center = a:vec3("center", ANY, ""),
        radius = a:number("radius", GT0, "> 0 [m]"), where = where }
end

--- ns.shape.ellipsoid{center, radii}
function ns.shape.ellipsoid(t)
    local where = where_of(2)
    local a = args(t, "ns.shape.ellipsoid", where, { "center", "radii" })
    return shape { type = "ellipsoid", center = a:vec3("center", ANY, ""),
        radii = a:vec3("radii", GT0, " > 0 [m]"), where = where }
end

--- ns.shape.box{center, size}  (axis-aligned; rotate it with ns.shape.rotate)
function ns.shape.box(t)
    local where = where_of(2)
    local a = args(t, "ns.shape.box", where, { "center", "size" })
    return shape { type = "box", center = a:vec3("center", ANY, ""),
        size = a:vec3("size", GT0, " > 0 [m]"), where = where }
end

local function segment_shape(kind, t, where, distinct)
    local ctor = "ns.shape." .. kind
    local a = args(t, ctor, where, { "a", "b", "radius" })
    local p, q = a:vec3("a", ANY, ""), a:vec3("b", ANY, "")
    if distinct and p[1] == q[1] and p[2] == q[2] and p[3] == q[3] then
        a:fail("a and b must differ (the axis runs from a to b)")
    end
    return shape { type = kind, a = p, b = q, radius = a:number("radius", GT0, "> 0 [m]"),
        where = where }
end

--- ns.shape.cylinder{a, b, radius}: flat-capped, between the centres a and b of its ends
function ns.shape.cylinder(t)
    return segment_shape("cylinder", t, where_of(2), true)
end

--- ns.shape.capsule{a, b, radius}: the points within radius of the segment ab
function ns.shape.capsule(t)
    return segment_shape("capsule", t, where_of(2), false)
end

local function shape_list(ctor, where, min, ...)
    local n = select("#", ...)
    if n < min then
        raise(where, ctor, fmt("needs at least %d shape%s (got %d)", min, min > 1 and "s" or "",
            n))
    end
    local list = {}
    for i = 1, n do
        local s = select(i, ...)
        if not is_shape(s) then
            raise(where, ctor, fmt("argument %d must be a shape, ns.shape.* or function(x, y, z) "
                .. "(got %s)", i, describe(s)))
        end
        list[i] = s
    end
    return list
end

--- ns.shape.union(s1, s2, ...): inside any of them
function ns.shape.union(...)
    local where = where_of(2)
    return shape { type = "union", children = shape_list("ns.shape.union", where, 1, ...),
        where = where }
end

--- ns.shape.intersection(s1, s2, ...): inside all of them
function ns.shape.intersection(...)
    local where = where_of(2)
    return shape { type = "intersection",
        children = shape_list("ns.shape.intersection", where, 1, ...), where = where }
end

--- ns.shape.difference(a, b): inside a and outside b
function ns.shape.difference(...)
    local where = where_of(2)
    if select("#", ...) ~= 2 then
        raise(where, "ns.shape.difference", fmt("takes exactly 2 shapes, a and b (got %d)",
            select("#", ...)))
    end
    local l = shape_list("ns.shape.difference", where, 2, ...)
    return shape { type = "difference", a = l[1], b = l[2], where = where }
end

-- Transforms: p = translate + scale * R q maps the child's point q to the world. Chained
-- transforms compose into one node.
local IDENTITY = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }

local function matmul(A, B)
    local C = {}
    for i = 0, 2 do
        for j = 0, 2 do
            C[3 * i + j + 1] = A[3 * i + 1] * B[j + 1] + A[3 * i + 2] * B[3 + j + 1]
                + A[3 * i + 3] * B[6 + j + 1]
        end
    end
    return C
end

local function matvec(A, v)
    return { A[1] * v[1] + A[2] * v[2] + A[3] * v[3], A[4] * v[1] + A[5] * v[2] + A[6] * v[3],
        A[7] * v[1] + A[8] * v[2] + A[9] * v[3] }
end

-- Applies (R, t, k) after the shape s (a transform node if s is one already).
local function transform(s, R, t, k, where)
    local child, R0, t0, k0 = s, IDENTITY, { 0, 0, 0 }, 1
    if kind_of(s) == "shape" and s.type == "transform" then
        child, R0, t0, k0 = s.child, s.rotation, s.translate, s.scale
    end
    -- p = t + k R (t0 + k0 R0 q) = (t + k R t0) + (k k0) (R R0) q
    local Rt0 = matvec(R, t0)
    return shape { type = "transform", child = child, rotation = matmul(R, R0),
        translate = { t[1] + k * Rt0[1], t[2] + k * Rt0[2], t[3] + k * Rt0[3] },
        scale = k * k0, where = where }
end

local function check_shape_arg(ctor, where, s)
    if not is_shape(s) then
        raise(where, ctor, fmt("argument 1 must be a shape, ns.shape.* or function(x, y, z) "
            .. "(got %s)", describe(s)))
    end
end

--- ns.shape.translate(s, {dx, dy, dz})
function ns.shape.translate(s, d)
    local where = where_of(2)
    check_shape_arg("ns.shape.translate", where, s)
    local v = vector(d, 3, ANY)
    if not v then
        raise(where, "ns.shape.translate", fmt("argument 2 must be {dx, dy, dz}: 3 numbers "
            .. "(got %s)", describe(d)))
    end
    return transform(s, IDENTITY, v, 1, where)
end

--- ns.shape.rotate(s, axis, angle): about an axis through the origin; axis is {x, y, z} or
--- "x", "y", "z"; angle in radians, right-handed
function ns.shape.rotate(s, axis, angle)
    local where = where_of(2)
    local ctor = "ns.shape.rotate"
    check_shape_arg(ctor, where, s)
    local named = { x = { 1, 0, 0 }, y = { 0, 1, 0 }, z = { 0, 0, 1 } }
    local u = named[axis] or vector(axis, 3, ANY)
    local len = u and math.sqrt(u[1] * u[1] + u[2] * u[2] + u[3] * u[3]) or 0
    if not (len > 0) or not is_finite(len) then
        raise(where, ctor, fmt("argument 2 (axis) must be \"x\", \"y\", \"z\" or a non-zero "
            .. "{x, y, z} (got %s)", describe(axis)))
    end
    if not is_finite(angle) then
        raise(where, ctor, fmt("argument 3 (angle) must be a number in radians (got %s)",
            describe(angle)))
    end
    local x, y, z = u[1] / len, u[2] / len, u[3] / len
    local c, sn = math.cos(angle), math.sin(angle)
    local C = 1 - c
    -- Rodrigues: R = c I + s [u]x + (1 - c) u u^T
    local R = {
        c + x * x * C, x * y * C - z * sn, x * z * C + y * sn,
        y * x * C + z * sn, c + y * y * C, y * z * C - x * sn,
        z * x * C - y * sn, z * y * C + x * sn, c + z * z * C,
    }
    return transform(s, R, { 0, 0, 0 }, 1, where)
end

--- ns.shape.scale(s, k): uniform scaling about the origin, k > 0
function ns.shape.scale(s, k)
    local where = where_of(2)
    check_shape_arg("ns.shape.scale", where, s)
    if not is_finite(k) or not (k > 0) then
        raise(where, "ns.shape.scale", fmt("argument 2 (factor) must be a number > 0 (got %s)",
            describe(k)))
    end
    return transform(s, IDENTITY, { 0, 0, 0 }, k, where)
end

-- Tissue -----------------------------------------------------------------------------------

ns.tissue = {}

local FACES = { "xmin", "xmax", "ymin", "ymax", "zmin", "zmax" }

--- ns.tissue.box{size, resolution, material, origin = {0, 0, 0}, fixed_faces}
-- The box spans origin .. origin + size. fixed_faces: list of "xmin", "xmax", ..., "zmax";
-- the nodes on those faces are held in place.
function ns.tissue.box(t)
    local where = where_of(2)
    local a = args(t, "ns.tissue.box", where,
        { "size", "resolution", "material", "origin", "fixed_faces" })
    local box = {
        type = "box",
        size = a:vec3("size", GT0, " > 0 [m]"),
        resolution = a:number("resolution", GT0, "> 0 [m]"),
        material = a:material("material"),
        origin = a:vec3("origin", ANY, "", { 0, 0, 0 }),
        fixed_faces = {},
        where = where,
    }
    local faces = t.fixed_faces
    if faces ~= nil then
        if type(faces) ~= "table" or kind_of(faces) then
            a:fail("fixed_faces must be a list of face names (got %s)", describe(faces))
        end
        local seen = {}
        for k, f in pairs(faces) do
            if math.type(k) ~= "integer" or k < 1 or k > #faces then
                a:fail("fixed_faces must be a list like {\"xmin\", \"zmin\"} (got key %s)",
                    describe(k))
            end
        end
        for i, f in ipairs(faces) do
            local ok = false
            for _, name in ipairs(FACES) do
                ok = ok or f == name
            end
            if not ok then
                a:fail("fixed_faces[%d] must be one of '%s' (got %s)", i, concat(FACES, "', '"),
                    describe(f))
            end
            if seen[f] then
                a:fail("fixed_faces lists '%s' twice", f)
            end
            seen[f] = true
            box.fixed_faces[i] = f
        end
    end
    return new(TISSUE, box)
end

local function check_bounds(a, v)
    if v == nil then
        return nil
    end
    local lo = type(v) == "table" and not kind_of(v) and vector(v[1], 3, ANY)
    local hi = type(v) == "table" and not kind_of(v) and vector(v[2], 3, ANY)
    local ok = lo and hi and #v == 2
    if ok then
        for i = 1, 3 do
            ok = ok and lo[i] < hi[i]
        end
    end
    if not ok then
        a:fail("bounds must be {{x0, y0, z0}, {x1, y1, z1}} with x0 < x1, y0 < y1, z0 < z1 "
            .. "(got %s)", describe(v))
    end
    return { lo, hi }
end

--- ns.tissue.shapes{resolution, regions = {{name, shape, material, fixed}, ...}, bounds}
-- Later regions override earlier ones where they overlap. bounds = {{x0,y0,z0},{x1,y1,z1}}
-- is the lattice box (the lattice is anchored at its min corner); it is required when a
-- region's shape is a Lua function, whose extent the mesher cannot know.
function ns.tissue.shapes(t)
    local where = where_of(2)
    local ctor = "ns.tissue.shapes"
    local a = args(t, ctor, where, { "resolution", "regions", "bounds" })
    local tissue = {
        type = "shapes",
        resolution = a:number("resolution", GT0, "> 0 [m]"),
        bounds = check_bounds(a, t.bounds),
        regions = {},
        where = where,
    }
    local regions = t.regions
    if regions == nil then
        a:fail("missing required field 'regions' (a list {{name =, shape =, material =}, ...})")
    end
    if type(regions) ~= "table" or kind_of(regions) or #regions == 0 then
        a:fail("regions must be a non-empty list {{name =, shape =, material =}, ...} (got %s)",
            describe(regions))
    end
    for k in pairs(regions) do
        if math.type(k) ~= "integer" or k < 1 or k > #regions then
            a:fail("regions must be a list (got key %s)", describe(k))
        end
    end
    local names = {}
    for i, r in ipairs(regions) do
        local ra = args(r, fmt("%s: regions[%d]", ctor, i), where,
            { "name", "shape", "material", "fixed" })
        local region = {
            name = ra:name("name"),
            shape = ra:shape("shape"),
            material = ra:material("material"),
            fixed = ra:boolean("fixed", false),
        }
        if names[region.name] then
            ra:fail("name '%s' is already used by regions[%d]", region.name, names[region.name])
        end
        names[region.name] = i
        if type(region.shape) == "function" and not tissue.bounds then
            ra:fail("shape is a Lua function: give the tissue bounds = {{x0, y0, z0}, "
                .. "{x1, y1, z1}} (the mesher cannot find a function's extent)")
        end
        tissue.regions[i] = region
    end
    return new(TISSUE, tissue)
end

local function is_tag(k)
    return math.type(k) == "integer" and k >= 1
end

--- ns.tissue.file{path, regions = {[tag] = material, ...}, names = {[tag] = "..."},
---                fixed = {tag, ...}}
-- A Gmsh .msh (4.1 or 2.2 ASCII) tetrahedral mesh; path is relative to the scenario's folder.
-- Every physical tag in the mesh needs a material in `regions`.
function ns.tissue.file(t)
    local where = where_of(2)
    local ctor = "ns.tissue.file"
    local a = args(t, ctor, where, { "path", "regions", "names", "fixed" })
    local tissue = { type = "file", path = a:string("path"), regions = {}, names = {},
        fixed = {}, where = where }
    local regions = t.regions
    if regions == nil then
        a:fail("missing required field 'regions' ({[tag] = material, ...})")
    end
    if type(regions) ~= "table" or kind_of(regions) or next(regions) == nil then
        a:fail("regions must be a table {[tag] = material, ...} (got %s)", describe(regions))
    end
    for tag, m in pairs(regions) do
        if not is_tag(tag) then
            a:fail("regions: keys must be Gmsh physical tags (integers >= 1) (got %s)",
                describe(tag))
        end
        if kind_of(m) ~= "material" then
            a:fail("regions[%d] must be a material (got %s)%s", tag, describe(m),
                material_hint(m))
        end
        tissue.regions[tag] = m
    end
    local names = t.names
    if names ~= nil then
        if type(names) ~= "table" or kind_of(names) then
            a:fail("names must be a table {[tag] = \"name\", ...} (got %s)", describe(names))
        end
        for tag, name in pairs(names) do
            if not is_tag(tag) or not regions[tag] then
                a:fail("names: %s is not a tag in regions", describe(tag))
            end
            if type(name) ~= "string" or name == "" then
                a:fail("names[%d] must be a non-empty string (got %s)", tag, describe(name))
            end
            local why = name_problem(name)
            if why then
                a:fail("names[%d] must be %s (got %s: %s)", tag, NAME_RULE, describe(name), why)
            end
            tissue.names[tag] = name
        end
    end
    local fixed = t.fixed
    if fixed ~= nil then
        if type(fixed) ~= "table" or kind_of(fixed) then
            a:fail("fixed must be a list of tags {tag, ...} (got %s)", describe(fixed))
        end
        for k, tag in pairs(fixed) do
            if math.type(k) ~= "integer" then
                a:fail("fixed must be a list of tags {tag, ...}")
            end
            if not is_tag(tag) or not regions[tag] then
                a:fail("fixed[%d]: %s is not a tag in regions", k, describe(tag))
            end
            tissue.fixed[tag] = true
        end
    end
    return new(TISSUE, tissue)
end

-- Parameters -------------------------------------------------------------------------------

--- ns.plan{target, avoid, clearance, method, seed}: a plan from the needle's tip as it is now
-- to the target named `target` where the tissue has carried it, around the obstacles named in
-- `avoid` (keeping `clearance` [m], default 1 mm), on the kinematic model (plan/;
-- docs/planning.md): method "rrt" (default) or "helix". Nothing is run. Returns {ok, path =
-- {{x, y, z}, ...} (every 1 mm), actions = {{twist [rad], insert [m], duty, rate [rad/m]}, ...},
-- error_mm, clearance_mm, length_mm, planning_ms} ({ok = false, message} when no path is
-- found). Only while the scenario runs: in its script or on_tick.
function ns.plan(t)
    local plan = require("needlesim.actions")._plan(t) -- not a tail call: errors name the caller
    return plan
end

--- ns.param(key, default): a scenario parameter that `needlesim run --set key=value` can change.
-- The value takes the type of `default` (a number, a boolean or a string); without --set it is
-- `default`. A --set key that no ns.param call reads is an error, so a misspelt key is caught.
function ns.param(key, default)
    local where = where_of(2)
    if type(key) ~= "string" or key == "" then
        raise(where, "ns.param", fmt("key must be a non-empty string (got %s)", describe(key)))
    end
    local td = type(default)
    if td ~= "number" and td ~= "boolean" and td ~= "string" then
        raise(where, "ns.param", fmt("default must be a number, a boolean or a string (got %s)",
            describe(default)))
    end
    local params = rawget(_G, "__ns_params")
    if type(params) == "table" then
        params[key] = true
    end
    local sets = rawget(_G, "__ns_sets")
    local v = type(sets) == "table" and sets[key] or nil
    if v == nil then
        return default
    end
    if td == "number" then
        local x = tonumber(v)
        if not is_finite(x) then
            raise(where, "ns.param", fmt("--set %s=%s: expected a number", key, v))
        end
        return x
    elseif td == "boolean" then
        if v ~= "true" and v ~= "false" then
            raise(where, "ns.param", fmt("--set %s=%s: expected true or false", key, v))
        end
        return v == "true"
    end
    return v
end

-- Needle -----------------------------------------------------------------------------------

local NEEDLE_FIELDS = { "kind", "diameter", "inner_diameter", "youngs", "density", "tip",
    "bevel_deg", "steering", "curvature", "bevel_force", "twist_friction" }
-- The two needles of the paper's brachytherapy runs (§4, Table 2: ProsSS and ProsFB): an 18 G
-- stainless-steel needle with a symmetric tip, and a flexible nitinol needle with a bevel tip
-- (the phantom experiments' 0.83 mm needle).
local NEEDLE_KINDS = {
    stiff = { diameter = 1.27e-3, inner_diameter = 0.84e-3, youngs = 200e9, density = 8000,
        tip = "symmetric", bevel_deg = 30 },
    flexible = { diameter = 0.83e-3, inner_diameter = 0, youngs = 50e9, density = 6450,
        tip = "bevel", bevel_deg = 30 },
}

--- ns.needle{kind, diameter, inner_diameter, youngs, density, tip, bevel_deg, steering, curvature,
--            bevel_force, twist_friction}
-- `kind` ("stiff" or "flexible", default "stiff") gives every field not given. `steering` is
-- how a bevel tip steers (docs/remeshing.md): "force" (the default: a lateral force at the
-- tip), "displacement" (the paper's §3.5: each cut moved sideways by d * tan(bevel)) or "arc"
-- (the nonholonomic model: the cut turns at curvature * tan(bevel) [1/m]). `bevel_force` is the
-- force model's k_b [N] (default 0.5): the tip is pushed sideways by k_b * tan(bevel).
-- `twist_friction` (default true): the tissue holds the shaft's twist with a stick/slip torque
-- of at most friction * diameter / 2 per unit length (docs/needle.md).
function ns.needle(t)
    local where = where_of(2)
    local a = args(t, "ns.needle", where, NEEDLE_FIELDS)
    local kind = a:choice("kind", { "stiff", "flexible" }, "stiff")
    local d = NEEDLE_KINDS[kind]
    local n = {
        kind = kind,
        diameter = a:number("diameter", GT0, "> 0 [m]", d.diameter),
        inner_diameter = a:number("inner_diameter", GE0, ">= 0 [m]", d.inner_diameter),
        youngs = a:number("youngs", GT0, "> 0 [Pa]", d.youngs),
        density = a:number("density", GT0, "> 0 [kg/m^3]", d.density),
        tip = a:choice("tip", { "bevel", "symmetric" }, d.tip),
        bevel_deg = a:number("bevel_deg", function(x) return x > 0 and x < 90 end,
            "in (0, 90) [degrees]", d.bevel_deg),
        steering = a:choice("steering", { "force", "displacement", "arc" }, "force"),
        curvature = a:number("curvature", GT0, "> 0 [1/m]", 10),
        bevel_force = a:number("bevel_force", function(x) return x >= 0 and x <= 10 end,
            "in [0, 10] [N]", 0.5),
        twist_friction = a:boolean("twist_friction", true),
        where = where,
    }
    if n.inner_diameter >= n.diameter then
        a:fail("inner_diameter (%g m) must be smaller than diameter (%g m)", n.inner_diameter,
            n.diameter)
    end
    if a:get("curvature") ~= nil and (n.steering ~= "arc" or n.tip ~= "bevel") then
        a:fail("curvature is the arc model's: it needs tip = \"bevel\" and steering = \"arc\"")
    end
    if a:get("bevel_force") ~= nil and (n.steering ~= "force" or n.tip ~= "bevel") then
        a:fail("bevel_force is the force model's: it needs tip = \"bevel\" and steering = " ..
            "\"force\"")
    end
    return new(NEEDLE, n)
end

-- Brachytherapy template and preloaded needles ---------------------------------------------

local TEMPLATE = make_kind("template", function() return "ns.template" end)
local TEMPLATE_FIELDS = { "origin", "spacing", "rows", "cols", "labels", "direction" }
local LABEL_FIELDS = { "cols", "rows" }
-- A model 6711 seed is 4.5 mm long, the usual spacer 5.5 mm: seed, spacer, seed... puts the
-- seeds' centres 1 cm apart along the needle.
local SEED_LENGTH, SPACER_LENGTH = 4.5e-3, 5.5e-3
local LOAD_SEEDS_MAX = 20

-- The distances of a load's seed centres behind the needle's tip [m], the deepest first; or
-- nil and what is wrong. A load is a list of "seed" and "spacer" from the tip back, or
-- {seeds = n, spacing = s}: n seeds s apart centre to centre (default 1 cm).
local function load_offsets(load)
    if type(load) ~= "table" or kind_of(load) then
        return nil, fmt("load must be a list of 'seed' and 'spacer', or {seeds = n, spacing = s} "
            .. "(got %s)", describe(load))
    end
    local out = {}
    if load.seeds ~= nil then
        for k in pairs(load) do
            if k ~= "seeds" and k ~= "spacing" then
                return nil, fmt("load: unknown field '%s' (known: seeds, spacing)", tostring(k))
            end
        end
        local n, sp = load.seeds, load.spacing or 1e-2
        if math.type(n) ~= "integer" or n < 1 or n > LOAD_SEEDS_MAX then
            return nil, fmt("load.seeds must be an integer in [1, %d] (got %s)", LOAD_SEEDS_MAX,
                describe(n))
        end
        if not is_finite(sp) or sp < SEED_LENGTH or sp > 0.05 then
            return nil, fmt("load.spacing must be a number in [%g, 0.05] [m] (got %s)",
                SEED_LENGTH, describe(sp))
        end
        for i = 1, n do
            out[i] = SEED_LENGTH / 2 + (i - 1) * sp
        end
        return out
    end
    local count = 0
    for _ in pairs(load) do
        count = count + 1
    end
    if count ~= #load or count < 1 or count > 2 * LOAD_SEEDS_MAX then
        return nil, fmt("load must be a list of 1 to %d 'seed' and 'spacer' (got %s)",
            2 * LOAD_SEEDS_MAX, describe(load))
    end
    local at = 0
    for i, item in ipairs(load) do
        if item == "seed" then
            out[#out + 1] = at + SEED_LENGTH / 2
            at = at + SEED_LENGTH
        elseif item == "spacer" then
            at = at + SPACER_LENGTH
        else
            return nil, fmt("load[%d] must be 'seed' or 'spacer' (got %s)", i, describe(item))
        end
    end
    if #out == 0 then
        return nil, "load carries no seed"
    end
    return out
end

local function label_list(a, labels, key, n, default)
    if labels == nil or labels[key] == nil then
        local out = {}
        for i = 1, n do
            out[i] = default(i)
        end
        return out
    end
    local l = labels[key]
    if type(l) ~= "table" or kind_of(l) or #l ~= n then
        a:fail("labels.%s must be a list of %d names (got %s)", key, n, describe(l))
    end
    local out, seen = {}, {}
    for i = 1, n do
        if type(l[i]) ~= "string" or not l[i]:match("^[%w.]+$") or #l[i] > 8 or seen[l[i]] then
            a:fail("labels.%s[%d] must be a distinct name of 1 to 8 letters, digits or '.' (got %s)",
                key, i, describe(l[i]))
        end
        seen[l[i]] = true
        out[i] = l[i]
    end
    return out
end

--- ns.template{origin, spacing, rows, cols, labels, direction}: a brachytherapy template, a
-- grid of cols x rows holes `spacing` apart (default 5 mm) through which needles go in along
-- `direction` (default {0, 0, 1}, into the patient). `origin` [m] is the first column's first
-- row, on the skin; columns run across the direction (along +x when it is z), rows along the
-- third axis (+y). A hole is named by its column's label and its row's, "C4"; the labels
-- default to "A", "B", ... and "1", "2", ..., and labels = {cols = {...}, rows = {...}} names
-- them as a clinical template's own markings do. The template holds `holes` (name -> point),
-- `names` (in column-major order), `direction`, and three functions: entry(hole) ->
-- {point, direction} for ns.scenario's `entry`; seeds(hole, depth, load) -> the planned seed
-- centres of a needle loaded with `load` pushed `depth` past the skin (act.needle leaves them
-- there when the tissue does not move); offsets(load) -> the seeds' distances behind the tip.
function ns.template(t)
    local where = where_of(2)
    local a = args(t, "ns.template", where, TEMPLATE_FIELDS)
    local origin = a:vec3("origin", ANY, " [m]")
    local spacing = a:number("spacing", function(x) return x >= 1e-3 and x <= 2e-2 end,
        "in [1e-3, 2e-2] [m]", 5e-3)
    local function count(k)
        return a:number(k, function(x) return x % 1 == 0 and x >= 1 and x <= 26 end,
            "(an integer in [1, 26])", 13)
    end
    local cols, rows = count("cols"), count("rows")
    local d = a:vec3("direction", ANY, "", { 0, 0, 1 })
    local len = math.sqrt(d[1] ^ 2 + d[2] ^ 2 + d[3] ^ 2)
    if len == 0 then
        a:fail("direction must not be zero")
    end
    d = { d[1] / len, d[2] / len, d[3] / len }
    local labels = a:get("labels")
    if labels ~= nil then
        args(labels, "ns.template: labels", where, LABEL_FIELDS)
    end
    local clab = label_list(a, labels, "cols", cols, function(i) return string.char(64 + i) end)
    local rlab = label_list(a, labels, "rows", rows, function(i) return tostring(i) end)
    -- the axes across the direction: x less its part along d (y if d is along x), then d x u
    local u = math.abs(d[1]) < 0.9 and { 1, 0, 0 } or { 0, 1, 0 }
    local ud = u[1] * d[1] + u[2] * d[2] + u[3] * d[3]
    u = { u[1] - ud * d[1], u[2] - ud * d[2], u[3] - ud * d[3] }
    local ul = math.sqrt(u[1] ^ 2 + u[2] ^ 2 + u[3] ^ 2)
    u = { u[1] / ul, u[2] / ul, u[3] / ul }
    local v = { d[2] * u[3] - d[3] * u[2], d[3] * u[1] - d[1] * u[3], d[1] * u[2] - d[2] * u[1] }
    local holes, names = {}, {}
    for c = 1, cols do
        for r = 1, rows do
            local name = clab[c] .. rlab[r]
            if holes[name] then
                a:fail("two holes are named '%s' (labels.cols and labels.rows run together)",
                    name)
            end
            local p = {}
            for k = 1, 3 do
                p[k] = origin[k] + (c - 1) * spacing * u[k] + (r - 1) * spacing * v[k]
            end
            holes[name] = p
            names[#names + 1] = name
        end
    end
    local tpl = { origin = origin, spacing = spacing, cols = cols, rows = rows, direction = d,
        holes = holes, names = names, offsets = load_offsets, where = where }
    local function hole(name, level)
        local p = type(name) == "string" and holes[name] or nil
        if not p then
            error(fmt("ns.template: no hole %s (holes %s to %s)", describe(name), names[1],
                names[#names]), level + 1)
        end
        return p
    end
    tpl.hole = function(name) return hole(name, 2) end
    tpl.entry = function(name)
        local p = hole(name, 2)
        return { point = { p[1], p[2], p[3] }, direction = { d[1], d[2], d[3] } }
    end
    tpl.seeds = function(name, depth, load)
        local p = hole(name, 2)
        if not is_finite(depth) or depth <= 0 then
            error(fmt("ns.template: seeds: depth must be a number > 0 [m] (got %s)",
                describe(depth)), 2)
        end
        local offs, why = load_offsets(load)
        if not offs then
            error("ns.template: seeds: " .. why, 2)
        end
        local out = {}
        for i, o in ipairs(offs) do
            local z = depth - o
            if z <= 0 then
                error(fmt("ns.template: seeds: the load's seed %d is %.1f mm behind the tip, past "
                    .. "the skin at depth %.1f mm", i, 1e3 * o, 1e3 * depth), 2)
            end
            out[i] = { p[1] + z * d[1], p[2] + z * d[2], p[3] + z * d[3] }
        end
        return out
    end
    return new(TEMPLATE, tpl)
end

--- ns.plan_implant{tissue, template, region, avoid, clearance, seeds, spacing, needles_max,
---                  prescription, strength, coverage, v150_max, grid, margin}: the needles of a seed
-- implant that bring `coverage` (default 0.95) of region `region` (a name in `tissue`, an
-- ns.tissue.shapes) to the prescription with the fewest insertions (docs/planning.md,
-- "Implant planning"): straight needles through the template's holes, each track's seeds
-- `spacing` apart (default 1 cm) centred in the region's span of it (the end seeds `margin`,
-- default 2 mm, inside), no track or seed within `clearance` (default 2 mm) of a region named in
-- `avoid`, at most `seeds` seeds (default 200) and `needles_max` needles (default: every
-- hole); TG-43 dose (I-125 model 6711, each seed `strength` U, default 0.5) on a `grid` of
-- spacing 2 mm in the undeformed anatomy, `prescription` Gy (default 145); needles that keep
-- V150 at most `v150_max` % (default 60) are preferred. Returns {needles =
-- {{hole, depth, load = {seeds, spacing}}, ...} in the template's order (for act.needle),
-- seeds = {{x, y, z}, ...} (needle by needle, deepest first, as template.seeds gives them),
-- v100, v150 [%], d90 [Gy], reached (v100 reached coverage), voxels, candidates (holes whose
-- track crosses the region), blocked (of those, too near an avoided region)}.
local IMPLANT_FIELDS = { "tissue", "template", "region", "avoid", "clearance", "seeds",
    "spacing", "needles_max", "prescription", "strength", "coverage", "v150_max", "grid",
    "margin" }
function ns.plan_implant(t)
    local where = where_of(2)
    local a = args(t, "ns.plan_implant", where, IMPLANT_FIELDS)
    local tissue, tpl = a:get("tissue"), a:get("template")
    if kind_of(tissue) ~= "tissue" or tissue.type ~= "shapes" then
        a:fail("tissue must be ns.tissue.shapes{...} (got %s)", describe(tissue))
    end
    if kind_of(tpl) ~= "template" then
        a:fail("template must be ns.template{...} (got %s)", describe(tpl))
    end
    local index, shapes = {}, {}
    for i, r in ipairs(tissue.regions) do
        index[r.name] = i
        shapes[i] = r.shape
    end
    local function region_index(name, what)
        if type(name) ~= "string" or not index[name] then
            local names = {}
            for i, r in ipairs(tissue.regions) do
                names[i] = r.name
            end
            a:fail("%s must name one of the tissue's regions (%s) (got %s)", what,
                table.concat(names, ", "), describe(name))
        end
        return index[name]
    end
    local target = region_index(a:get("region"), "region")
    local avoid = {}
    local av = a:get("avoid")
    if av ~= nil then
        if type(av) ~= "table" or kind_of(av) or #av > 32 then
            a:fail("avoid must be a list of at most 32 region names (got %s)", describe(av))
        end
        for i, name in ipairs(av) do
            avoid[i] = region_index(name, fmt("avoid[%d]", i))
            if avoid[i] == target then
                a:fail("avoid[%d] is the region to cover", i)
            end
        end
    end
    local function integer(k, lo, hi, default)
        return a:number(k, function(x) return x % 1 == 0 and x >= lo and x <= hi end,
            fmt("(an integer in [%d, %d])", lo, hi), default)
    end
    local holes = {}
    for i, name in ipairs(tpl.names) do
        holes[i] = tpl.holes[name]
    end
    local args_c = {
        regions = shapes,
        target = target,
        avoid = avoid,
        holes = holes,
        direction = tpl.direction,
        clearance = a:number("clearance", function(x) return x >= 0 and x < 0.1 end,
            "in [0, 0.1) [m]", 2e-3),
        seeds = integer("seeds", 1, 10000, 200),
        spacing = a:number("spacing", function(x) return x >= SEED_LENGTH and x <= 0.05 end,
            fmt("in [%g, 0.05] [m]", SEED_LENGTH), 1e-2),
        needles = integer("needles_max", 1, #holes, #holes),
        prescription = a:number("prescription", function(x) return x > 0 and x <= 1000 end,
            "in (0, 1000] [Gy]", 145),
        strength = a:number("strength", function(x) return x > 0 and x <= 10 end,
            "in (0, 10] [U]", 0.5),
        coverage = a:number("coverage", function(x) return x > 0 and x <= 1 end, "in (0, 1]",
            0.95),
        v150_max = a:number("v150_max", function(x) return x > 0 and x <= 100 end,
            "in (0, 100] [%]", 60),
        grid = a:number("grid", function(x) return x >= 1e-3 and x <= 1e-2 end,
            "in [1e-3, 1e-2] [m]", 2e-3),
        margin = a:number("margin", function(x) return x >= 0 and x <= 0.02 end,
            "in [0, 0.02] [m]", 2e-3),
        seeds_per_needle = LOAD_SEEDS_MAX,
        tip_offset = SEED_LENGTH / 2, -- the tip beyond the deepest seed's centre (load_offsets)
    }
    local r, why = __ns_plan_implant(args_c)
    if not r then
        a:fail("%s", (tostring(why):gsub("^implant plan: ", "")))
    end
    local plan = { needles = {}, seeds = {}, v100 = r.v100, v150 = r.v150, d90 = r.d90,
        reached = r.reached, voxels = r.voxels, candidates = r.candidates, blocked = r.blocked }
    for i, n in ipairs(r.needles) do
        local load = { seeds = n.seeds, spacing = args_c.spacing }
        local hole = tpl.names[n.hole]
        local depth = n.deepest + load_offsets(load)[1]
        plan.needles[i] = { hole = hole, depth = depth, load = load }
        for _, p in ipairs(tpl.seeds(hole, depth, load)) do
            plan.seeds[#plan.seeds + 1] = p
        end
    end
    return plan
end

-- Scenario ---------------------------------------------------------------------------------

local SCENARIO_FIELDS = { "name", "tissue", "description", "seed", "dt", "duration", "needle",
    "entry", "targets", "obstacles", "markers", "seeds", "camera", "script", "on_tick",
    "accuracy", "solver", "live", "dosimetry", "template" }
-- Accepted now and checked by the stages that use them (later versions).
local RESERVED = {}

local ENTRY_FIELDS = { "point", "direction", "bevel_toward" }
local TARGET_FIELDS = { "name", "at", "tolerance" }
local MARKER_FIELDS = { "name", "at" }
local OBSTACLE_FIELDS = { "name", "region" }
local SEED_FIELDS = { "target" }
local CAMERA_FIELDS = { "views", "fps", "frame_every", "cut_normal", "tet_edges",
    "friction_colours" }
local VIEWS = { side = true, top = true, axis = true, cutaway3d = true, trus = true }
local SOLVER_FIELDS = { "tolerance", "check_tolerance", "lazy_threshold", "tip_block" }
local ACCURACY_FIELDS = { "tip", "front" }
local LIVE_FIELDS = { "script", "entries", "accuracy", "front" }
local DOSIMETRY_FIELDS = { "prescription", "strength", "source", "spacing", "prostate", "urethra",
    "rectum", "plan" }
-- sim/ns_limits.h's NS_LIMIT_DOSE_* (the engine checks them again)
local DOSE_PLAN_MAX = 1000

--- ns.economy(tip, front): the cheapest settings on a measured speed-against-accuracy front
--- (scripts/needlesim/fronts.lua, written by tools/speed_accuracy.py) whose measured error
--- stays within `tip` metres (phantom: the tip and markers against the converged run at equal
--- depth; brachytherapy: the seeds): a new table {dt, refine, tolerance, lazy_threshold,
--- tip_error, cost, label}, refine the mesh refinement it was measured with (1: the
--- scenario's own mesh). front: "phantom" (gel block, flexible bevel needle; the default) or
--- "brachytherapy". Raises when no measured setting is accurate enough.
local function economy(tip, front, where, own_mesh)
    front = front or "phantom"
    if not is_finite(tip) or tip <= 0 then
        raise(where, "ns.economy", fmt("the tip accuracy must be a number > 0 [m] (got %s)",
            describe(tip)))
    end
    local fronts = require "needlesim.fronts"
    local rows = fronts[front]
    if type(front) ~= "string" or rows == nil then
        local known = {}
        for k in pairs(fronts) do
            known[#known + 1] = k
        end
        sort(known)
        raise(where, "ns.economy", fmt("no measured front '%s' (known: %s)", tostring(front),
            concat(known, ", ")))
    end
    local best
    for _, r in ipairs(rows) do -- sorted by cost
        if not own_mesh or r.refine == 1 then
            if r.tip_error <= tip then
                local copy = {}
                for k, v in pairs(r) do
                    copy[k] = v
                end
                return copy
            end
            if not best or r.tip_error < best.tip_error then
                best = r
            end
        end
    end
    raise(where, "ns.economy", fmt("accuracy %g m: no measured setting on the '%s' front%s "
        .. "reaches it (the most accurate, %s, is %g m off the reference; "
        .. "docs/performance.md)", tip, front, own_mesh and " on the scenario's own mesh" or "",
        best and best.label or "none", best and best.tip_error or 0))
end

function ns.economy(tip, front)
    return economy(tip, front, where_of(2), false)
end

-- accuracy = 0.5e-3 or {tip = 0.5e-3, front = "phantom"}: the engine runs with the cheapest
-- measured dt and solver settings that keep the tip within it (ns.economy); the scenario then
-- gives neither dt nor solver.
local function accuracy_of(v, t, where)
    if v == nil then
        return nil
    end
    local tip, front = v, nil
    if type(v) == "table" and not kind_of(v) then
        local a = args(v, "ns.scenario: accuracy", where, ACCURACY_FIELDS)
        tip = a:number("tip", GT0, "> 0 [m]")
        front = a:string("front", "phantom")
    elseif not is_finite(v) or v <= 0 then
        raise(where, "ns.scenario", fmt("accuracy must be a number > 0 [m] or {tip, front} "
            .. "(got %s)", describe(v)))
    end
    if t.dt ~= nil or t.solver ~= nil then
        raise(where, "ns.scenario", "accuracy chooses dt and the solver settings from the "
            .. "measured front: give accuracy, or dt and solver, not both")
    end
    -- the scenario's mesh is its own: only settings measured on it (refine 1) can be promised
    local r = economy(tip, front, where, true)
    return { tip = tip, front = front or "phantom", label = r.label, dt = r.dt,
        refine = r.refine, tolerance = r.tolerance, lazy_threshold = r.lazy_threshold,
        tip_error = r.tip_error, cost = r.cost }
end

-- solver = {tolerance, check_tolerance, lazy_threshold, tip_block}: the coupled solve's relative
-- residuals (the paper's tau_sol and tau_check, §3.6.1), the lazy-Jacobian threshold (§3.6.3)
-- and whether the stale factor's block at the tip is made current every step (docs/solvers.md,
-- "The tail"). The engine's defaults (1e-8, 1e-6, 1e-2, false) when absent;
-- docs/performance.md measures what they cost.
local function solver_of(v, where)
    if v == nil then
        return nil
    end
    local a = args(v, "ns.scenario: solver", where, SOLVER_FIELDS)
    local s = {
        tolerance = a:number("tolerance", function(x) return x > 0 and x < 1 end, "in (0, 1)",
            OPTIONAL),
        check_tolerance = a:number("check_tolerance", function(x) return x > 0 and x < 1 end,
            "in (0, 1)", OPTIONAL),
        lazy_threshold = a:number("lazy_threshold", function(x) return x >= 0 and x < 1 end,
            "in [0, 1)", OPTIONAL),
        tip_block = a:boolean("tip_block", false),
    }
    if s.check_tolerance and s.check_tolerance < (s.tolerance or 1e-8) then
        a:fail("check_tolerance (%g) must not be below tolerance (%g%s)", s.check_tolerance,
            s.tolerance or 1e-8, s.tolerance and "" or ", the default")
    end
    return s
end

-- camera = {views, fps, frame_every, cut_normal, tet_edges, friction_colours}: what the frames
-- and the video show (docs/rendering.md). Defaults: the side view, 25 frames a second, a frame
-- every 1/(fps dt) steps (real time), the cut through the insertion axis facing the camera.
local function camera_of(v, where, dt)
    local a = args(v or {}, "ns.scenario: camera", where, CAMERA_FIELDS)
    local c = { views = {} }
    local views = a:get("views")
    if views == nil then
        c.views = { "side" }
    else
        if type(views) ~= "table" or kind_of(views) or #views < 1 or #views > 3 then
            a:fail("views must be a list of 1 to 3 of 'side', 'top', 'axis', 'cutaway3d', 'trus' (got %s)",
                describe(views))
        end
        local seen = {}
        for i, name in ipairs(views) do
            if not VIEWS[name] then
                a:fail("views[%d] must be 'side', 'top', 'axis', 'cutaway3d' or 'trus' (got %s)", i,
                    describe(name))
            end
            if seen[name] then
                a:fail("views[%d]: '%s' is listed twice", i, name)
            end
            seen[name] = true
            c.views[i] = name
        end
    end
    c.fps = a:number("fps", function(x) return x > 0 and x <= 120 end, "in (0, 120]", 25)
    c.frame_every = a:number("frame_every",
        function(x) return x >= 1 and x <= 1e6 and x % 1 == 0 end, "(an integer in [1, 1e6] [steps])", math.max(1, math.floor(1 / (c.fps * dt) + 0.5)))
    c.cut_normal = a:vec3("cut_normal", ANY, "", OPTIONAL)
    if c.cut_normal then
        local n = c.cut_normal
        if n[1] == 0 and n[2] == 0 and n[3] == 0 then
            a:fail("cut_normal must not be zero")
        end
    end
    c.tet_edges = a:boolean("tet_edges", true)
    c.friction_colours = a:boolean("friction_colours", true)
    return c
end

-- A list field of tables, each checked by `one(args, i)`; names unique when `named`.
local function list_of(v, where, field, fields, one, named)
    if v == nil then
        return {}
    end
    if type(v) ~= "table" or kind_of(v) then
        raise(where, "ns.scenario", fmt("%s must be a list of {%s} (got %s)", field,
            concat(fields, ", "), describe(v)))
    end
    local out, names = {}, {}
    for i, item in ipairs(v) do
        local a = args(item, fmt("ns.scenario: %s[%d]", field, i), where, fields)
        local x = one(a)
        if named then
            if names[x.name] then
                a:fail("name '%s' is used by %s[%d] already", x.name, field, names[x.name])
            end
            names[x.name] = i
        end
        out[i] = x
    end
    return out
end

-- entry = {point, direction}: where the needle's sleeve meets the skin and the way it points.
local function entry_of(v, where, ctor)
    if v == nil then
        return nil
    end
    local a = args(v, ctor or "ns.scenario: entry", where, ENTRY_FIELDS)
    local e = { point = a:vec3("point", ANY, " [m]"), direction = a:vec3("direction", ANY, "") }
    local d = e.direction
    local len = math.sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3])
    if len == 0 then
        a:fail("direction must not be zero")
    end
    e.direction = { d[1] / len, d[2] / len, d[3] / len }
    local b = a:vec3("bevel_toward", ANY, "", OPTIONAL)
    if b then
        local bd = b[1] * e.direction[1] + b[2] * e.direction[2] + b[3] * e.direction[3]
        local p = { b[1] - bd * e.direction[1], b[2] - bd * e.direction[2], b[3] - bd * e.direction[3] }
        local lp = math.sqrt(p[1] * p[1] + p[2] * p[2] + p[3] * p[3])
        if lp < 1e-9 * math.sqrt(b[1] * b[1] + b[2] * b[2] + b[3] * b[3]) or lp == 0 then
            a:fail("bevel_toward must not be parallel to direction")
        end
        e.bevel_toward = { p[1] / lp, p[2] / lp, p[3] / lp }
    end
    return e
end

-- targets = {{name, at, tolerance}, ...}: points in the tissue the needle tip should reach.
local function targets_of(v, where)
    if v == nil then
        return {}
    end
    if type(v) ~= "table" or kind_of(v) then
        raise(where, "ns.scenario", fmt("targets must be a list of {name, at, tolerance} (got %s)",
            describe(v)))
    end
    local out, names = {}, {}
    for i, tv in ipairs(v) do
        local a = args(tv, fmt("ns.scenario: targets[%d]", i), where, TARGET_FIELDS)
        local tg = { name = a:name("name"), at = a:vec3("at", ANY, " [m]"),
            tolerance = a:number("tolerance", GT0, "> 0 [m]") }
        if names[tg.name] then
            a:fail("name '%s' is used by targets[%d] already", tg.name, names[tg.name])
        end
        names[tg.name] = i
        out[i] = tg
    end
    return out
end

-- live = {script, entries}: what a live session (`needlesim live`, docs/live.md) takes from the
-- scenario. script = true runs the scenario's script first (a scripted set-up) and hands the
-- needle to the trainee when it ends (default false: the trainee drives from the start);
-- entries = {{point, direction, bevel_toward}, ...}: where each {"next_needle": true} puts
-- the next needle, in turn (default: the scenario's entry again); accuracy = TIP [m] with
-- front = NAME ("phantom" default): the live session's dt and solver settings, the cheapest
-- measured on that front within TIP on the scenario's own mesh (ns.economy; `needlesim live
-- --accuracy` overrides it; `needlesim run` keeps the scenario's own).
local function live_of(v, where)
    if v == nil then
        return nil
    end
    local a = args(v, "ns.scenario: live", where, LIVE_FIELDS)
    local l = { script = a:boolean("script", false), entries = {} }
    l.accuracy = a:number("accuracy", function(x) return x >= 1e-9 and x <= 1 end,
        "in [1e-9, 1] [m]", OPTIONAL)
    l.front = a:string("front", OPTIONAL)
    if l.front ~= nil and l.accuracy == nil then
        a:fail("front = '%s' without accuracy: the front is where the accuracy is looked up",
            l.front)
    end
    if l.accuracy ~= nil then
        l.front = l.front or "phantom"
        economy(l.accuracy, l.front, where, true)
    end
    local es = a:get("entries")
    if es ~= nil then
        if type(es) ~= "table" or kind_of(es) or #es < 1 or #es > 64 then
            a:fail("entries must be a list of 1 to 64 entries {point, direction} (got %s)",
                describe(es))
        end
        for i, e in ipairs(es) do
            l.entries[i] = entry_of(e, where, fmt("ns.scenario: live.entries[%d]", i))
        end
    end
    return l
end

-- dosimetry = {prescription, strength, source, spacing, prostate, urethra, rectum, plan}: the
-- TG-43 dose of the seeds as planned and as delivered, read as the guidelines' dose-volume
-- figures (docs/brachytherapy.md). prescription [Gy] (145, I-125 monotherapy), strength: each
-- seed's air-kerma strength [U], spacing: the dose grid's [m], prostate/urethra/rectum: region
-- names, plan: the planned seed centres in the undeformed anatomy (default: the targets of the
-- scenario's `seeds`, in order).
local function dosimetry_of(v, t, where)
    if v == nil then
        return nil
    end
    local a = args(v, "ns.scenario: dosimetry", where, DOSIMETRY_FIELDS)
    local d = {
        prescription = a:number("prescription", function(x) return x > 0 and x <= 1000 end,
            "in (0, 1000] [Gy]", 145),
        strength = a:number("strength", function(x) return x > 0 and x <= 10 end,
            "in (0, 10] [U]", 0.5),
        source = a:choice("source", { "i125_6711" }, "i125_6711"),
        spacing = a:number("spacing", function(x) return x >= 0.5e-3 and x <= 5e-3 end,
            "in [0.5e-3, 5e-3] [m]", 1e-3),
        prostate = a:name("prostate", nil, "prostate"),
        urethra = a:name("urethra", nil, "urethra"),
        rectum = a:name("rectum", nil, "rectum"),
        plan = {},
    }
    local plan = a:get("plan")
    if plan ~= nil then
        if type(plan) ~= "table" or kind_of(plan) or #plan < 1 or #plan > DOSE_PLAN_MAX then
            a:fail("plan must be a list of 1 to %d seed centres {x, y, z} [m] (got %s)",
                DOSE_PLAN_MAX, describe(plan))
        end
        for i, p in ipairs(plan) do
            local out = vector(p, 3, ANY)
            if not out then
                a:fail("plan[%d] must be {x, y, z}: 3 numbers [m] (got %s)", i, describe(p))
            end
            d.plan[i] = out
        end
    elseif t.seeds == nil then
        a:fail("needs a plan: plan = {{x, y, z}, ...} or the scenario's seeds = {{target = ...}}")
    end
    return d
end

--- ns.scenario{name, tissue, description, seed, dt, duration, script, on_tick, ...}
function ns.scenario(t)
    local where = where_of(2)
    local a = args(t, "ns.scenario", where, SCENARIO_FIELDS)
    local sc = {
        name = a:string("name"),
        description = a:string("description", OPTIONAL),
        seed = a:number("seed", function(x) return math.type(x) == "integer" or x % 1 == 0 end,
            "(an integer)", OPTIONAL),
        dt = a:number("dt", GT0, "> 0 [s]", OPTIONAL),
        duration = a:number("duration", GT0, "> 0 [s]", OPTIONAL),
        script = a:func("script"),
        on_tick = a:func("on_tick"),
        where = where,
    }
    local tissue = t.tissue
    if tissue == nil then
        a:fail("missing required field 'tissue' (ns.tissue.box{...}, ns.tissue.shapes{...} or "
            .. "ns.tissue.file{...})")
    end
    if kind_of(tissue) ~= "tissue" then
        a:fail("tissue must be ns.tissue.box{...}, ns.tissue.shapes{...} or ns.tissue.file{...} "
            .. "(got %s)", describe(tissue))
    end
    sc.tissue = tissue
    local needle = t.needle
    if needle ~= nil and kind_of(needle) ~= "needle" then
        a:fail("needle must be ns.needle{...} (got %s)", describe(needle))
    end
    sc.needle = needle
    sc.entry = entry_of(t.entry, where)
    sc.targets = targets_of(t.targets, where)
    sc.markers = list_of(t.markers, where, "markers", MARKER_FIELDS, function(m)
        return { name = m:name("name"), at = m:vec3("at", ANY, " [m]") }
    end, true)
    sc.obstacles = list_of(t.obstacles, where, "obstacles", OBSTACLE_FIELDS, function(o)
        return { name = o:name("name"), region = o:string("region") }
    end, true)
    sc.seeds = list_of(t.seeds, where, "seeds", SEED_FIELDS, function(o)
        return { target = o:string("target") }
    end, false)
    local tnames = {}
    for _, tg in ipairs(sc.targets) do
        tnames[tg.name] = true
    end
    for i, sd in ipairs(sc.seeds) do
        if not tnames[sd.target] then
            raise(where, "ns.scenario", fmt("seeds[%d]: target '%s' is not one of the targets",
                i, sd.target))
        end
    end
    sc.solver = solver_of(t.solver, where)
    sc.accuracy = accuracy_of(t.accuracy, t, where)
    if sc.accuracy then
        local e = sc.accuracy
        sc.dt = e.dt
        sc.solver = { tolerance = e.tolerance, check_tolerance = math.min(0.5, 100 * e.tolerance),
            lazy_threshold = e.lazy_threshold }
    end
    sc.camera = camera_of(t.camera, where, sc.dt or 0.01)
    sc.live = live_of(t.live, where)
    sc.dosimetry = dosimetry_of(t.dosimetry, t, where)
    if t.template ~= nil and kind_of(t.template) ~= "template" then
        a:fail("template must be ns.template{...} (got %s)", describe(t.template))
    end
    sc.template = t.template
    for _, k in ipairs(RESERVED) do
        sc[k] = t[k]
    end
    return new(SCENARIO, sc)
end

return ns
