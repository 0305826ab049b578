#!/bin/bash
# act.steer, ns.plan and `needlesim bench --planning` end to end (docs/planning.md): a steered
# two_cylinders run's report.json has the `steering` object's keys; ns.plan returns a plan from
# a script; bad act.steer / ns.plan fields fail with one line naming the script's file:line;
# `bench --planning --layouts 1 --json` has the contract's keys (not the bars: one layout is too
# few to measure them; the bars are the benchmark's, docs/planning.md).
#
# usage: tests/test_steer_run.sh NEEDLESIM_BINARY SOURCE_ROOT
set -u

BIN=${1:?usage: test_steer_run.sh NEEDLESIM_BINARY SOURCE_ROOT}
ROOT=$(cd "${2:?usage: test_steer_run.sh NEEDLESIM_BINARY SOURCE_ROOT}" && pwd)
export NEEDLESIM_SCRIPTS=$ROOT/scripts
export NEEDLESIM_ASSETS=$ROOT/assets
export OPENBLAS_NUM_THREADS=1

TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-steer.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
OUT=$TMP/stdout
ERR=$TMP/stderr
PASSED=0
FAILED=0

pass() {
    echo "ok    $1"
    PASSED=$((PASSED + 1))
}

fail() {
    echo "FAIL  $1: $2"
    [ -s "$ERR" ] && sed 's/^/      stderr: /' "$ERR" | head -5
    FAILED=$((FAILED + 1))
}

# scenario NAME LUA: two_cylinders with LUA as the first lines of its script (then it ends).
scenario() {
    sed -e "s|^    script = function()|    script = function()\n        $2\n        do return end|" \
        "$ROOT/scenarios/two_cylinders.lua" >"$TMP/$1.lua"
}

# the steering object after 150 steps of act.steer (RRT around both rods)
scenario steer 'act.steer { target = "goal", avoid = { "near rod", "far rod" }, method = "rrt" }'
"$BIN" run "$TMP/steer.lua" --no-render --quiet --steps 150 -o "$TMP/steer" >"$OUT" 2>"$ERR"
if [ $? != 0 ]; then
    fail "steered run" "exit non-zero"
elif python3 - "$TMP/steer/report.json" <<'PY'; then
import json, math, sys
s = json.load(open(sys.argv[1]))["steering"]
for k in ("replans", "planning_ms", "min_clearance_mm", "final_error_mm", "obstacle_entered"):
    assert k in s, k
assert s["replans"] >= 1 and s["planning_ms"]["median"] >= 0 and s["planning_ms"]["p95"] >= 0
assert s["min_clearance_mm"] > 0 and math.isfinite(s["final_error_mm"])
assert s["obstacle_entered"] is False and s["method"] == "rrt" and s["target"] == "goal"
PY
    pass "report.json steering keys"
else
    fail "report.json steering keys" "missing or wrong"
fi

# act.steer's predicted arc in the frames (docs/planning.md, "In the frames"): light blue in the
# frame at step 150, mid-steering, and none in the first frame, before any replan
"$BIN" run "$TMP/steer.lua" --quiet --steps 150 --frames --frame-every 150 --width 480 \
    --height 270 -o "$TMP/steer_f" >"$OUT" 2>"$ERR"
if [ $? = 0 ] && python3 -B - "$TMP/steer_f/frames" "$ROOT/tests" <<'PY' >"$TMP/py_f" 2>&1; then
import sys
sys.path.insert(0, sys.argv[2])
import png_rgb
def light_blue(path):  # ns_scene_plan_rgb (140, 225, 250), lit: not the needle's blue
    w, h, rows = png_rgb.read(path)
    return sum(1 for row in rows for x in range(w)
               if row[3 * x + 2] > 180 and row[3 * x + 1] > 150 and
               row[3 * x + 1] > row[3 * x] + 40 and row[3 * x + 2] > row[3 * x] + 60 and
               10 * row[3 * x + 1] > 7 * row[3 * x + 2])  # green near blue: not the needle
first, last = light_blue(sys.argv[1] + "/000000.png"), light_blue(sys.argv[1] + "/000001.png")
print("light-blue pixels: %d before, %d while steering" % (first, last))
assert first == 0 and last >= 20, (first, last)
PY
    pass "the planned arc drawn while steering ($(tail -1 "$TMP/py_f"))"
else
    fail "the planned arc in the frames" "$(tail -1 "$TMP/py_f")"
fi

# ns.plan from a script: a plan that reaches the goal with the rods' clearance
scenario plan 'local p = ns.plan { target = "goal", avoid = { "near rod", "far rod" }, clearance = 2e-3 }; assert(p.ok and #p.actions >= 1 and #p.path > 50 and p.error_mm < 1 and p.clearance_mm >= 2, "ns.plan: a bad plan")'
"$BIN" run "$TMP/plan.lua" --no-render --quiet --steps 2 -o "$TMP/plan" >"$OUT" 2>"$ERR" &&
    pass "ns.plan in a script" || fail "ns.plan in a script" "exit non-zero"

# expect_error NAME TEXT LUA: the run fails with one line naming the script's line and TEXT
expect_error() {
    scenario bad "$3"
    "$BIN" run "$TMP/bad.lua" --no-render --quiet --steps 2 -o "$TMP/bad" >"$OUT" 2>"$ERR"
    local rc=$? line
    line=$(($(grep -n '^    script = function()' "$TMP/bad.lua" | cut -d: -f1) + 1))
    if [ $rc = 0 ]; then
        fail "$1" "exit 0"
    elif [ "$(wc -l <"$ERR")" != 1 ] || ! grep -qF -- "$TMP/bad.lua:$line: $2" "$ERR"; then
        fail "$1" "stderr is not one line holding 'bad.lua:$line: $2'"
    else
        pass "$1"
    fi
}
expect_error "steer: unknown target" \
    "act.steer: 'target' must name a target of the scenario (got nope; targets: goal)" \
    'act.steer { target = "nope" }'
expect_error "steer: bad method" 'act.steer: method must be "helix" or "rrt" (got x)' \
    'act.steer { target = "goal", method = "x" }'
expect_error "steer: unknown obstacle" "act.steer: avoid[1] = rod is not an obstacle" \
    'act.steer { target = "goal", avoid = { "rod" } }'
expect_error "steer: replan_every" "act.steer: replan_every must be a number in [1e-4, 0.1]" \
    'act.steer { target = "goal", replan_every = 0 }'
expect_error "steer: unknown field" "act.steer: unknown field 'bogus'" \
    'act.steer { target = "goal", bogus = 1 }'
expect_error "plan: clearance" "ns.plan: clearance must be a number >= 0 [m] (got -1)" \
    'ns.plan { target = "goal", clearance = -1 }'
expect_error "plan: not a table" "ns.plan: expected a table of fields" 'ns.plan(3)'
expect_error "steer: rollout not a boolean" "act.steer: rollout must be true or false (got number)" \
    'act.steer { target = "goal", rollout = 1 }'

# Rollouts in the simulator (docs/planning.md): a copy of the world stepped 20 steps ends where
# the run's own tip then goes, bit for bit, and the run's state hash is the same without the
# call; a run that writes a checkpoint refuses rollouts.
model=force # the arc model's rollouts end the same way (checked by hand)
"$BIN" run "$ROOT/tests/data/rollout.lua" --no-render -o "$TMP/ro" --set steering=$model \
    >"$OUT" 2>"$ERR"
rc1=$?
cp "$ERR" "$TMP/ro_err"
h1=$(grep -o 'state hash [0-9a-f]*' "$OUT" "$ERR" | head -1 | awk '{print $3}')
"$BIN" run "$ROOT/tests/data/rollout.lua" --no-render -o "$TMP/ro2" --set steering=$model \
    --set rollout=false >"$OUT" 2>"$ERR"
rc2=$?
h2=$(grep -o 'state hash [0-9a-f]*' "$OUT" "$ERR" | head -1 | awk '{print $3}')
line=$(grep '^rollout: ' "$TMP/ro_err")
ends=$(echo "$line" | sed -n 's/.* end \(.*\); the run.s tip \(.*\)$/\1|\2/p')
if [ $rc1 = 0 ] && [ $rc2 = 0 ] && [ -n "$ends" ] && [ "${ends%|*}" = "${ends#*|}" ] &&
    [ -n "$h1" ] && [ "$h1" = "$h2" ]; then
    pass "rollout ($model model): ends where the run goes, bit for bit; state hash $h1 with and without it"
else
    fail "rollout ($model model)" "exit $rc1/$rc2, ends '$ends', hashes '$h1' '$h2'"
fi
# act.steer's rollout refused in a run that writes a checkpoint, at the scenario's line
scenario steer_ro 'act.steer { target = "goal", rollout = true }'
"$BIN" run "$TMP/steer_ro.lua" --no-render --quiet --steps 20 -o "$TMP/ro3" \
    --checkpoint-at 0.05 "$TMP/ro3.ck" >"$OUT" 2>"$ERR"
rc=$?
line=$(($(grep -n '^    script = function()' "$TMP/steer_ro.lua" | cut -d: -f1) + 1))
if [ $rc != 0 ] && [ "$(wc -l <"$ERR")" = 1 ] &&
    grep -qF "steer_ro.lua:$line: act.steer: rollouts read the world at their tick" "$ERR" &&
    [ ! -e "$TMP/ro3" ]; then
    pass "act.steer's rollout refused in a run that writes a checkpoint, at the script's line"
else
    fail "rollout with --checkpoint-at" "exit $rc: $(head -c 300 "$ERR")"
fi

# bench --planning: the contract's keys (one layout: its open and closed loop runs; the bars are
# the benchmark's, docs/planning.md)
"$BIN" bench --planning --layouts 1 --json >"$OUT" 2>"$ERR"
if [ $? != 0 ]; then
    fail "bench --planning" "exit non-zero"
elif python3 - "$OUT" <<'PY'; then
import json, sys
b = json.load(open(sys.argv[1]))
assert b["layouts"] == 1 and len(b["runs"]) == 1
for loop in ("open_loop", "closed_loop"):
    o = b[loop]
    for k in ("success_rate", "mean_error_mm", "min_clearance_mm", "replans"):
        assert k in o, (loop, k)
    assert 0 <= o["success_rate"] <= 1 and o["mean_error_mm"] >= 0
assert b["planning_ms"]["median"] >= 0 and b["planning_ms"]["p95"] >= b["planning_ms"]["median"]
assert b["closed_loop"]["replans"] > 0
PY
    pass "bench --planning --json keys"
else
    fail "bench --planning --json keys" "missing or wrong"
fi
"$BIN" bench --planning --layouts 0 >"$OUT" 2>"$ERR"
[ $? = 2 ] && grep -qF -- "--layouts must be an integer in 1..1000" "$ERR" &&
    pass "bench --planning --layouts 0 refused" || fail "--layouts 0" "not refused with 2"

echo "$PASSED passed, $FAILED failed"
[ "$FAILED" = 0 ]
