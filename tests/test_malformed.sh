#!/bin/bash
# Untrusted input (docs/reliability.md): malformed and hostile scenarios, mesh paths and command
# lines. Each case must end within 60 s with the exit status it names (1 bad input, 2 bad
# command line), exactly one line on stderr holding the expected words, and nothing left behind:
# no output folder, no temporary file, nothing else new in the folder it ran from.
#
# usage: tests/test_malformed.sh NEEDLESIM_BINARY SOURCE_DIR
set -u

BIN=$(realpath "${1:?usage: test_malformed.sh NEEDLESIM_BINARY SOURCE_DIR}")
SRC=$(cd "${2:?usage: test_malformed.sh NEEDLESIM_BINARY SOURCE_DIR}" && pwd)
DATA=$SRC/tests/data/malformed
export NEEDLESIM_SCRIPTS=$SRC/scripts

TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-malformed.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
WORK=$TMP/work # each case runs here, on a copy of the cases
mkdir -p "$WORK"
cp "$DATA"/*.lua "$WORK"/
mkfifo "$WORK/fifo.msh" "$WORK/fifo_scenario.lua"
ERR=$TMP/stderr
PASSED=0
FAILED=0

listing() { (cd "$WORK" && find . -mindepth 1 | LC_ALL=C sort); }

# expect NAME STATUS WORDS -- ARGS...: runs the binary in $WORK.
expect() {
    local name=$1 status=$2 words=$3
    shift 4
    local before after rc lines t0 t1
    before=$(listing)
    t0=$(date +%s)
    (cd "$WORK" && timeout 60 "$BIN" "$@") >/dev/null 2>"$ERR"
    rc=$?
    t1=$(date +%s)
    after=$(listing)
    lines=$(wc -l <"$ERR")
    local why=""
    if [ "$rc" -eq 124 ]; then
        why="did not end within 60 s"
    elif [ "$rc" -ne "$status" ]; then
        why="exit $rc, expected $status"
    elif [ "$lines" -ne 1 ]; then
        why="$lines lines on stderr, expected 1"
    elif ! grep -qF -- "$words" "$ERR"; then
        why="stderr lacks '$words'"
    elif [ "$before" != "$after" ]; then
        why="left files behind: $(diff <(echo "$before") <(echo "$after") | grep '^>' | head -3 | tr '\n' ' ')"
    fi
    if [ -z "$why" ]; then
        echo "ok    $name ($((t1 - t0)) s)"
        PASSED=$((PASSED + 1))
    else
        echo "FAIL  $name: $why"
        sed 's/^/      stderr: /' "$ERR" | head -3
        FAILED=$((FAILED + 1))
    fi
    rm -rf "$WORK/out"
}

# Scenarios changed after their constructors checked them: the value is named where C uses it.
R="run --no-render -o out"
expect "erroring __index, field removed" 1 "targets[1].tolerance" -- $R meta_index.lua
expect "__len returning 1.5" 1 "dt must be" -- $R meta_len.lua
expect "camera.frame_every = 0" 1 "camera.frame_every" -- $R frame_every_zero.lua
expect "dt = NaN" 1 "dt must be" -- $R dt_nan.lua
expect "entry.point = {\"a\", {}, nil}" 1 "entry.point" -- $R entry_point.lua
expect "duration = 1e9" 1 "duration must be" -- $R duration_huge.lua
expect "tolerance = 0" 1 "tolerance must be" -- $R tolerance_zero.lua
# Scripts that would run for ever, or in C code that no hook sees.
expect "__gc finalizer" 1 "__gc" -- $R gc_loop.lua
expect "backtracking string.find" 1 "matching steps" -- $R pattern_backtrack.lua
expect "endless loop catching its error" 1 "instruction limit exceeded" -- $R pcall_loop.lua
expect "memory hog" 1 "not enough memory" -- $R memory_hog.lua
expect "memory filled by small strings" 1 "not enough memory" -- check memory_fill.lua
expect "shape function called per vertex" 1 "instruction limit exceeded" -- check shape_calls.lua
expect "error(nil)" 1 "error_nil.lua:1:" -- $R error_nil.lua
expect "coroutine.yield in a shape function" 1 "yield_in_shape.lua:5: attempt to yield" -- check yield_in_shape.lua
expect "a scenario name of 1,000 bytes" 1 "name is 1000 bytes long" -- check long_name.lua
# Files that never end or block.
expect "mesh path /dev/zero" 1 "not a regular file" -- check dev_zero.lua
expect "mesh path a FIFO" 1 "not a regular file" -- check fifo_mesh.lua
expect "scenario path a FIFO" 1 "not a regular file" -- check fifo_scenario.lua
expect "resolution under the lattice limit" 1 "fits" -- check resolution_fine.lua
# Controls beyond physical bounds.
expect "act.insert speed 1e9 m/s" 1 "speed must be a number in (0, 0.5]" -- $R speed_huge.lua
expect "sim.control.v_insert 3e9" 1 "beyond its limit" -- $R control_huge.lua
expect "act.twist angle 1e12" 1 "angle must be a number in" -- $R twist_huge.lua
expect "next_needle direction {\"x\", 0, 1}" 1 "next_needle.direction" -- $R next_needle_bad.lua
# Output paths.
expect "-o ''" 2 "-o: expected a path" -- run --no-render -o "" base.lua
expect "--record /dev/full" 1 "not a regular file" -- $R --record /dev/full meta_index.lua
mkdir -p "$WORK/taken/report.json"
expect "report.json is a folder" 1 "not a regular file" -- run --no-render -o taken base.lua
rm -rf "$WORK/taken"

# A script that never ends stops at the default limit of simulated time with a report.
cat >"$WORK/forever.lua" <<'EOF'
local act = require "needlesim.actions"
local sc = require("base").scenario(function() while true do act.wait { time = 1 } end end)
sc.dt = 0.05
return sc
EOF
(cd "$WORK" && timeout 120 "$BIN" run --no-render -o out forever.lua) >/dev/null 2>"$ERR"
rc=$?
if [ "$rc" -eq 0 ] && grep -q '"script_finished": false' "$WORK/out/report.json" &&
    grep -q '"time_limit_s": 120' "$WORK/out/report.json"; then
    echo "ok    endless act.wait: stopped at the time limit with a report"
    PASSED=$((PASSED + 1))
else
    echo "FAIL  endless act.wait: exit $rc, report: $(grep -E 'script_finished|time_limit' "$WORK/out/report.json" 2>/dev/null | tr -d '\n')"
    FAILED=$((FAILED + 1))
fi
rm -rf "$WORK/out" "$WORK/forever.lua"

# SIGTERM during a run: nothing left, not even the temporary files.
cat >"$WORK/slow.lua" <<'EOF'
local act = require "needlesim.actions"
local sc = require("base").scenario(function() while true do act.wait { time = 1 } end end)
sc.dt = 0.001
return sc
EOF
before=$(listing)
(cd "$WORK" && exec "$BIN" run --no-render -o out slow.lua --record log.csv) >/dev/null 2>"$ERR" &
pid=$!
for _ in $(seq 1 100); do [ -f "$WORK/out/.trajectory.csv.part" ] && break; sleep 0.1; done
sleep 0.5
kill -TERM "$pid"
wait "$pid"
rc=$?
after=$(listing)
if [ "$rc" -ne 0 ] && [ "$before" = "$after" ] && grep -q "interrupted" "$ERR"; then
    echo "ok    SIGTERM mid-run: exit $rc, nothing left"
    PASSED=$((PASSED + 1))
else
    echo "FAIL  SIGTERM mid-run: exit $rc; left: $(diff <(echo "$before") <(echo "$after") | grep '^>' | tr '\n' ' ')"
    sed 's/^/      stderr: /' "$ERR" | head -3
    FAILED=$((FAILED + 1))
fi

echo "$PASSED passed, $FAILED failed"
[ "$FAILED" -eq 0 ]
