-- A teaching video (issue 39; docs/rendering.md "Authored videos"): why a bevel-tip needle
-- curves, and how half a turn of its base steers it the other way.
--
--   needlesim run scenarios/lesson_bevel_steering.lua --video lesson.mp4
--
-- The physics is the double-bend gel phantom's (phantom_double_bend.lua: the paper's §4,
-- Fig. 9), inserted more slowly so that the captions can be read; the script's act.card,
-- act.chapter, act.caption, act.camera and act.slow_motion give the video its voice and change
-- nothing else: the state hash is the same with --no-render. The video is about 65 s long, in
-- three chapters. Frames are taken every 4 steps (dt 10 ms) at 25 frames a second: real time
-- but where slowed.
local ns = require "needlesim"
local act = require "needlesim.actions"
local single = require "phantom_single_bend"

local speed = 0.003 -- 3 mm/s

return ns.scenario {
  name = "lesson: steering a bevel-tip needle",
  description = "a narrated double bend in a gel phantom: why the bevel curves, how a half turn steers",
  tissue = single.tissue,
  dt = single.dt,
  needle = ns.needle { kind = "flexible", bevel_deg = single.needle.bevel_deg, steering = "arc" },
  entry = single.entry,
  markers = single.markers,
  camera = { views = { "top" }, frame_every = 4, fps = 25 },
  script = function()
    act.card { title = "Steering a bevel-tip needle",
      text = "Why a flexible needle with a slanted tip curves, and how a half turn of its base " ..
        "makes it curve the other way. A gel phantom seen from above, cut level with the needle.",
      duration = 7 }

    act.chapter { title = "Why a bevel tip curves" }
    act.caption { text = "The needle is thin nitinol, its tip cut at 30 degrees: the slanted face " ..
      "looks to one side.", duration = 4 }
    act.wait { time = 4 }
    act.caption { text = "As it cuts, the gel pushes harder on the slanted face than on the " ..
      "other side of the tip.", duration = 7 }
    act.insert { speed = speed, depth = 0.024 }
    act.caption { text = "That unbalanced push bends the flexible needle towards its bevel: " ..
      "the path curves.", duration = 7 }
    act.insert { speed = speed, depth = 0.05 }

    act.chapter { title = "A half turn steers it back" }
    act.camera { zoom = 2.5, duration = 1.5 }
    act.caption { text = "Now the base turns half a turn. The tip turns with it, and the bevel " ..
      "faces the other way.", duration = 4 }
    act.wait { time = 1.5 }
    act.slow_motion { factor = 4, duration = 0.6 }
    act.twist { angle = math.pi, rate = math.pi / 0.5 } -- half a turn in 0.5 s, paused
    act.caption { text = "Nothing moved sideways yet: only the tip's orientation changed.",
      duration = 3 }
    act.wait { time = 2 }
    act.camera { zoom = 1, duration = 1.5 }
    act.wait { time = 1.5 }

    act.chapter { title = "The S-curve" }
    act.caption { text = "Pushed on, the tip curves the other way from where it turned: the " ..
      "path becomes an S.", duration = 7 }
    act.insert { speed = speed, depth = 0.075 }
    act.caption { text = "Surgeons steer this way around what must not be touched: turn the " ..
      "base, keep pushing.", duration = 7 }
    act.insert { speed = speed, depth = 0.10 }
    act.caption { text = "The whole path, seen turning about the needle's axis.", duration = 5 }
    act.camera { orbit = 60, duration = 3 }
    act.wait { time = 3 }
    act.camera { orbit = -60, duration = 3 }
    act.wait { time = 3 }

    act.card { title = "What to remember",
      text = "A bevel tip curves towards its bevel. Half a turn of the base reverses the curve. " ..
        "Spinning it all the way in goes straight.",
      duration = 7 }
  end,
}
