-- An authored video's cues on a small gel block (tests/test_run.sh): a card, two chapters,
-- captions, a camera move and slow motion around a twist. `--set bad=NAME` swaps in a bad cue:
-- each is refused naming the script's line (the actions) or the cue's field (the engine).
local ns = require "needlesim"
local act = require "needlesim.actions"
local bad = ns.param("bad", "")

local function bad_cue()
  if bad == "caption_text" then act.caption { duration = 1 } end
  if bad == "slow_factor" then act.slow_motion { factor = 0.5, duration = 1 } end
  if bad == "camera_view" then act.camera { view = "front" } end
  if bad == "card_long" then act.card { title = string.rep("x", 201) } end
  if bad == "chapter_field" then act.chapter { title = "a", at = 3 } end
end

return ns.scenario {
  name = "video cues",
  tissue = ns.tissue.box { size = { 0.04, 0.02, 0.02 }, origin = { 0, -0.01, -0.01 },
    resolution = 0.005, material = ns.materials.gel, fixed_faces = { "xmax" } },
  dt = 0.01,
  needle = ns.needle { kind = "flexible", bevel_deg = 30, steering = "arc" },
  entry = { point = { 0, 0, 0 }, direction = { 1, 0, 0 }, bevel_toward = { 0, 1, 0 } },
  camera = { views = { "top" }, frame_every = 2, fps = 25 },
  script = function()
    act.card { title = "Video cues", text = "a test", duration = 1 }
    act.chapter { title = "In" }
    act.caption { text = "inserting", duration = 1 }
    bad_cue()
    act.insert { speed = 0.01, depth = 0.01 }
    act.chapter { title = "Turn; = # \\ escaped" }
    act.camera { zoom = 2, orbit = 30, duration = 0.2 }
    act.slow_motion { factor = 4, duration = 0.3 }
    act.twist { angle = math.pi, rate = math.pi / 0.2 }
    act.chapter { title = "On" }
    act.insert { speed = 0.01, depth = 0.02 }
  end,
  on_tick = bad == "raw_kind" and function(sim)
    if sim.step == 5 then sim.control.video = { { kind = "zoom" } } end
  end or nil,
}
