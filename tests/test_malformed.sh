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
cp "$DATA"/*.lua "$DATA"/*.csv "$WORK"/
mkfifo "$WORK/fifo.msh" "$WORK/fifo_scenario.lua"
mkdir "$WORK/moddir.lua" # require_dir.lua: a module that is a folder
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
    # -k: a case that ignores SIGTERM (see rep_loop_run.lua) must not hang the suite
    (cd "$WORK" && timeout -k 5 60 "$BIN" "$@") >/dev/null 2>"$ERR"
    rc=$?
    t1=$(date +%s)
    after=$(listing)
    lines=$(wc -l <"$ERR")
    local why=""
    if [ "$rc" -eq 124 ] || [ "$rc" -eq 137 ]; then
        why="did not end within 60 s"
    elif [ "$rc" -ne "$status" ]; then
        why="exit $rc, expected $status"
    elif [ "$lines" -ne 1 ]; then
        why="$lines lines on stderr, expected 1"
    elif ! grep -qF -- "$words" "$ERR"; then
        why="stderr lacks '$words'"
    elif [ "$before" != "$after" ]; then
        why="left files behind (>) or removed files (<): $(diff <(echo "$before") <(echo "$after") | grep '^[<>]' | head -3 | tr '\n' ' ')"
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
expect "needle.steering = \"sideways\"" 1 "needle.steering must be" -- $R steering_raw.lua
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

# ---- issue 32 attack, passing cases: regressions worth keeping ----
# The Lua libraries' own limits, reached from a scenario: one line, with the file and line.
expect "string.format(\"%99999d\")" 1 "fmt_width.lua:2: invalid conversion" -- $R fmt_width.lua
expect "string.rep with a separator past 2^31" 1 "more than a scenario may hold" -- $R rep_sep.lua
expect "unbounded Lua recursion" 1 "deep_recursion.lua:2: stack overflow" -- $R deep_recursion.lua
expect "load() of 10^5 nested parentheses" 1 "load_nested.lua:3:" -- $R load_nested.lua
expect "table.sort with an inconsistent comparator" 1 "invalid order function" -- $R sort_inconsistent.lua
expect "string metatable __index hijacked" 1 "string_meta.lua:2: hijacked" -- $R string_meta.lua
expect "error value whose __tostring errors" 1 "tostring_error.lua:2:" -- $R tostring_error.lua
expect "require of a folder" 1 "module not found" -- check require_dir.lua
expect "require 'a..b'" 1 "invalid module name" -- check require_dots.lua
expect "require of itself" 1 "circular require" -- check require_self.lua
# Trainee logs.
expect "log with a NUL byte" 1 "log_nul.csv:2:" -- $R --replay log_nul.csv short.lua
expect "log row with 12 columns" 1 "log_columns.csv:2: expected 7 comma-separated fields" -- $R --replay log_columns.csv short.lua
expect "log with a hex float" 1 "log_hex.csv:2: v_insert_m_s must be a finite number" -- $R --replay log_hex.csv short.lua
expect "log with 1e308 m/s" 1 "log_1e308.csv:2: v_insert_m_s 1e+308" -- $R --replay log_1e308.csv short.lua
expect "log without a header" 1 "log_no_header.csv:1: the header must be" -- $R --replay log_no_header.csv short.lua
expect "log of another scenario" 1 "--rescore replays it anyway" -- $R --replay log_other_scenario.csv short.lua
expect "log next_needle with a zero direction" 1 "log_next_zero.csv:2: next_needle" -- $R --replay log_next_zero.csv short.lua
# Command lines.
touch "$WORK/a_file"
expect "-o names a file" 1 "is not a folder" -- run --no-render -o a_file short.lua
rm -f "$WORK/a_file"
expect "--threads 65" 2 "--threads" -- $R --threads 65 short.lua
expect "--width 8193" 2 "--width" -- run -o out --width 8193 short.lua
expect "--video without .mp4" 2 "--video" -- run -o out --video out short.lua
expect "--steps 2000001" 2 "--steps" -- $R --steps 2000001 short.lua
expect "--record and --replay the same file" 2 "the same file" -- $R --record log_nul.csv --replay log_nul.csv short.lua
expect "unknown option" 2 "unknown option" -- $R --bogus short.lua

# ---- found by an attack on the input handling (issue 32), fixed ----
# C work the instruction budget does not see (hangs; the run's case also ignores SIGTERM).
expect "string.rep in a loop while loading" 1 "rep_loop.lua:4:" -- check rep_loop.lua
expect "string.rep in a loop in the script" 1 "rep_loop_run.lua:4:" -- $R rep_loop_run.lua
expect "a shape DAG of 2^40 leaves" 1 "shape_dag.lua" -- check shape_dag.lua
# Files outside the run's own outputs: an earlier run's outputs, the scenario, the report.
mkdir -p "$WORK/prev" && echo '{}' >"$WORK/prev/report.json" && echo t_s >"$WORK/prev/trajectory.csv"
expect "a failed run keeps an earlier run's outputs" 1 "error_nil.lua:1:" -- run --no-render -o prev error_nil.lua
rm -rf "$WORK/prev"
expect "-o a/b/c removes the parents it made" 1 "error_nil.lua:1:" -- run --no-render -o new/deep/out error_nil.lua
rm -rf "$WORK/new"
cp "$WORK/short.lua" "$WORK/record_self.lua"
expect "--record names the scenario file" 2 "--record" -- $R --record record_self.lua record_self.lua
rm -f "$WORK/record_self.lua"
expect "--record names -o's report.json" 2 "--record" -- $R --record out/report.json short.lua
expect "--record ./X --replay X" 2 "the run's own input" -- $R --record ./log_nohash_short.csv --replay log_nohash_short.csv short.lua
# More than one line on stderr.
expect "log without #scenario_hash, too short" 1 "ends after 1 steps" -- $R --replay log_nohash_short.csv short.lua
expect "--rescore, log too short" 1 "ends after 1 steps" -- $R --rescore --replay log_rescore_short.csv short.lua
expect "--trainee with a newline" 2 "--trainee" -- $R --trainee $'a\nb' short.lua
expect "unknown option with a newline" 2 "unknown option" -- $R $'--x\ny' short.lua
expect "--set key with a newline" 2 "--set" -- $R --set $'bad\nkey=1' param_label.lua
expect "--set value with a newline (breaks the --record log)" 2 "--set" -- $R --record rec.csv --set $'label=a\nt_s,evil' param_label.lua
rm -f "$WORK/rec.csv"
expect "material model with a newline" 1 "model must be" -- $R nl_model.lua
expect "scenario where with a newline" 1 "dt must be" -- $R nl_where.lua
expect "shape type with a newline" 1 "unknown shape type" -- check nl_shape_type.lua
# print() writes to stderr (stdout carries --json): a scenario's own prints come before the one
# error line, which is the last (docs/reliability.md).
(cd "$WORK" && timeout 60 "$BIN" check print_then_error.lua) >/dev/null 2>"$ERR"
rc=$?
if [ "$rc" -eq 1 ] && [ "$(wc -l <"$ERR")" -eq 2 ] && tail -1 "$ERR" | grep -qF "print_then_error.lua:3: bad"; then
    echo "ok    print, then an error: the error is the last line"
    PASSED=$((PASSED + 1))
else
    echo "FAIL  print, then an error: exit $rc, last line: $(tail -1 "$ERR")"
    FAILED=$((FAILED + 1))
fi
# Messages without the file and line.
expect "error(\"boom\", 0)" 1 "error_level0.lua:2:" -- check error_level0.lua
expect "error(\"\", 0)" 1 "error_empty.lua:2:" -- check error_empty.lua
expect "__tostring message without a position" 1 "error_tostring_nl.lua:3:" -- check error_tostring_nl.lua
expect "__tostring calling tostring on itself" 1 "tostring_recursion.lua:" -- check tostring_recursion.lua
expect "on_tick yields" 1 "on_tick_yield.lua:3:" -- $R on_tick_yield.lua
expect "on_tick replaced by a number" 1 "on_tick_replaced.lua:" -- $R on_tick_replaced.lua

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


# ---- signals and output files (issue 32) ----
# ok_or_fail NAME WHY: WHY empty passes.
ok_or_fail() {
    if [ -z "$2" ]; then
        echo "ok    $1"
        PASSED=$((PASSED + 1))
    else
        echo "FAIL  $1: $2"
        sed 's/^/      stderr: /' "$ERR" | head -3
        FAILED=$((FAILED + 1))
    fi
}

# SIGTERM while the tissue is meshed (C code, no Lua hook): it must end promptly, not when the
# mesher, the build and the first step are done.
sigterm_case() { # NAME SIGNALS: sends SIGTERM once or twice (0.3 s apart) 1 s into meshing
    local name=$1 twice=$2 before after pid rc t0 t1 why=""
    before=$(listing)
    (cd "$WORK" && exec "$BIN" run --no-render -o out slow_mesh.lua) >/dev/null 2>"$ERR" &
    pid=$!
    for _ in $(seq 1 100); do [ -f "$WORK/out/.trajectory.csv.part" ] && break; sleep 0.1; done
    sleep 1
    t0=$(date +%s)
    kill -TERM "$pid"
    if [ "$twice" = 1 ]; then sleep 0.3; kill -TERM "$pid" 2>/dev/null; fi
    for _ in $(seq 1 600); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null
    wait "$pid"
    rc=$?
    t1=$(date +%s)
    after=$(listing)
    if [ $((t1 - t0)) -gt 5 ]; then
        why="ended $((t1 - t0)) s after SIGTERM"
    elif [ "$before" != "$after" ]; then
        why="left: $(diff <(echo "$before") <(echo "$after") | grep '^[<>]' | tr '\n' ' ')"
    elif [ "$(wc -l <"$ERR")" -ne 1 ]; then
        why="$(wc -l <"$ERR") lines on stderr (exit $rc)"
    fi
    rm -rf "$WORK/out"
    ok_or_fail "$name" "$why"
}
sigterm_case "SIGTERM while meshing: ends within 5 s" 0
sigterm_case "SIGTERM twice while meshing: the output folder removed, one line" 1

# check --mesh-out writes "FILE.tmp" with fopen: a symbolic link there is followed, and the
# file it points to (outside the outputs) is overwritten.
echo precious >"$WORK/victim.txt"
ln -s victim.txt "$WORK/m.msh.tmp"
(cd "$WORK" && timeout -k 5 60 "$BIN" check short.lua --mesh-out m.msh) >/dev/null 2>"$ERR"
why=""
[ "$(cat "$WORK/victim.txt")" = precious ] || why="victim.txt (the target of m.msh.tmp) was overwritten"
ok_or_fail "--mesh-out with a symbolic link at FILE.tmp" "$why"
rm -f "$WORK/victim.txt" "$WORK/m.msh.tmp" "$WORK/m.msh"

# The contact sheet's temporary file is opened with fopen (not O_EXCL | O_NOFOLLOW like the
# others): a hard link planted at out/summary.png.part has its other name overwritten.
echo precious >"$WORK/victim.txt"
mkdir -p "$WORK/out"
ln "$WORK/victim.txt" "$WORK/out/summary.png.part"
(cd "$WORK" && timeout -k 5 60 "$BIN" run -o out --width 64 --height 64 --quiet short.lua) >/dev/null 2>"$ERR"
why=""
printf 'precious\n' | cmp -s - "$WORK/victim.txt" || why="victim.txt (hard-linked at out/summary.png.part) was overwritten"
ok_or_fail "a hard link at out/summary.png.part" "$why"
rm -rf "$WORK/victim.txt" "$WORK/out"

echo "$PASSED passed, $FAILED failed"
[ "$FAILED" -eq 0 ]
