#!/bin/bash
# `needlesim plan` end to end (docs/planning.md): on two_cylinders the --json object has the
# contract's keys, keeps the clearance asked for and reaches the goal within its tolerance, for
# both methods; -o DIR writes DIR/plan.json and DIR/path.csv (the same points) and nothing else;
# the same seed gives the same plan; an unknown target, a bad option and an impossible clearance
# exit non-zero with one line. `run --plan DIR` draws the path in the frames (light blue where a
# run without it has none); a bad path.csv stops the run before it writes anything.
#
# usage: tests/test_plan.sh NEEDLESIM_BINARY SOURCE_ROOT
set -u

BIN=${1:?usage: test_plan.sh NEEDLESIM_BINARY SOURCE_ROOT}
ROOT=$(cd "${2:?usage: test_plan.sh NEEDLESIM_BINARY SOURCE_ROOT}" && pwd)
export NEEDLESIM_SCRIPTS=$ROOT/scripts
SC=scenarios/two_cylinders.lua

TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-plan.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
OUT=$TMP/stdout
ERR=$TMP/stderr
PASSED=0
FAILED=0
RC=0

pass() {
    echo "ok    $1"
    PASSED=$((PASSED + 1))
}

fail() {
    echo "FAIL  $1: $2"
    [ -s "$ERR" ] && sed 's/^/      stderr: /' "$ERR" | head -5
    FAILED=$((FAILED + 1))
}

run() {
    (cd "$ROOT" && "$BIN" "$@") >"$OUT" 2>"$ERR"
    RC=$?
}

# check_plan NAME FILE CLEARANCE_MM: the keys, clearance >= asked, error <= tolerance.
check_plan() {
    local why
    why=$(python3 - "$2" "$3" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
asked = float(sys.argv[2])
keys = ["error_mm", "clearance_mm", "length_mm", "planning_ms", "method", "path", "actions"]
missing = [k for k in keys if k not in d]
if missing:
    print("missing keys: " + ", ".join(missing)); sys.exit(1)
if not d["clearance_mm"] >= asked:
    print("clearance %g mm < asked %g mm" % (d["clearance_mm"], asked)); sys.exit(1)
if not d["error_mm"] <= d["tolerance_mm"]:
    print("error %g mm > tolerance %g mm" % (d["error_mm"], d["tolerance_mm"])); sys.exit(1)
if not (len(d["path"]) >= 2 and all(len(p) == 3 for p in d["path"])):
    print("path is not a list of [x, y, z]"); sys.exit(1)
if not (d["length_mm"] > 0 and d["planning_ms"] >= 0 and len(d["actions"]) >= 1):
    print("length, planning time or actions out of range"); sys.exit(1)
for a in d["actions"]:
    if not (0 <= a["duty"] <= 1 and a["insert_mm"] >= 0):
        print("an action out of range: %r" % a); sys.exit(1)
PY
)
    if [ $? = 0 ]; then pass "$1"; else fail "$1" "$why"; fi
}

for method in rrt helix; do
    run plan $SC --target goal --json --method $method
    if [ $RC != 0 ]; then
        fail "plan --json --method $method" "exit $RC"
    else
        cp "$OUT" "$TMP/$method.json"
        check_plan "plan --json --method $method" "$TMP/$method.json" 1
    fi
done

run plan $SC --target goal --json --clearance 0.004
if [ $RC = 0 ]; then check_plan "plan --clearance 0.004" "$OUT" 4; else fail "plan --clearance 0.004" "exit $RC"; fi

# the same seed, the same plan (planning_ms aside)
run plan $SC --target goal --json --clearance 0.004 --seed 5
grep -v planning_ms "$OUT" >"$TMP/a"
run plan $SC --target goal --json --clearance 0.004 --seed 5
grep -v planning_ms "$OUT" >"$TMP/b"
if cmp -s "$TMP/a" "$TMP/b"; then pass "same seed, same plan"; else fail "same seed, same plan" "differ"; fi

run plan $SC --target goal -o "$TMP/out"
if [ $RC = 0 ] && [ -f "$TMP/out/plan.json" ] &&
    [ "$(ls -A "$TMP/out" | tr '\n' ' ')" = "path.csv plan.json " ]; then
    check_plan "plan -o DIR writes DIR/plan.json and DIR/path.csv alone" "$TMP/out/plan.json" 1
else
    fail "plan -o DIR" "exit $RC, folder: $(ls -A "$TMP/out" 2>&1)"
fi
grep -q "predicted error" "$OUT" && pass "text output" || fail "text output" "no 'predicted error'"
if python3 - "$TMP/out" <<'PY'
import csv, json, sys
path = json.load(open(sys.argv[1] + "/plan.json"))["path"]
rows = list(csv.reader(open(sys.argv[1] + "/path.csv")))
assert rows[0] == ["x_m", "y_m", "z_m"], rows[0]
assert [[float(v) for v in r] for r in rows[1:]] == path, "path.csv differs from plan.json's path"
print("    %d points" % len(path))
PY
then
    pass "path.csv holds plan.json's path, point for point"
else
    fail "path.csv" "differs from plan.json"
fi

# run --plan DIR: the plan's path in the frames, light blue (ns_scene_plan_rgb, lit), where the
# same run without it has none (two_cylinders runs no act.steer)
light_blue() { # PNG -> the count of its light-blue pixels
    PYTHONPATH="$ROOT/tests" python3 -B -c '
import sys, png_rgb
w, h, rows = png_rgb.read(sys.argv[1])
print(sum(1 for r in rows for i in range(0, 3 * w, 3)
          if r[i + 2] > 200 and r[i + 1] > 170 and r[i] < 190 and r[i + 2] - r[i] > 40))' "$1"
}
run run $SC --plan "$TMP/out" --steps 200 --frames --frame-every 200 -o "$TMP/with" --quiet
with=$RC
run run $SC --steps 200 --frames --frame-every 200 -o "$TMP/without" --quiet
if [ $with = 0 ] && [ $RC = 0 ]; then
    a=$(light_blue "$TMP/with/frames/000001.png")
    b=$(light_blue "$TMP/without/frames/000001.png")
    if [ "$a" -gt 200 ] && [ "$b" = 0 ]; then
        pass "run --plan DIR draws the path: $a light-blue pixels at step 200, none without it"
    else
        fail "run --plan DIR" "$a light-blue pixels with the plan, $b without"
    fi
else
    fail "run --plan DIR" "exit $with / $RC"
fi

# expect_fail NAME STATUS TEXT -- ARGS: exit STATUS, one line on stderr holding TEXT
expect_fail() {
    local name=$1 status=$2 text=$3
    shift 4
    run "$@"
    if [ $RC != "$status" ]; then
        fail "$name" "exit $RC, expected $status"
    elif [ "$(wc -l <"$ERR")" != 1 ] || ! grep -qF -- "$text" "$ERR"; then
        fail "$name" "stderr is not one line holding '$text'"
    else
        pass "$name"
    fi
}
expect_fail "unknown target" 1 "no target named 'nowhere' (targets: 'goal')" -- \
    plan $SC --target nowhere --json
[ ! -s "$OUT" ] && pass "unknown target prints nothing on stdout" || fail "unknown target" "stdout"
expect_fail "no --target" 2 "--target NAME is required" -- plan $SC
expect_fail "bad --method" 2 "--method must be rrt or helix" -- plan $SC --target goal --method x
expect_fail "bad --clearance" 2 "--clearance must be" -- plan $SC --target goal --clearance -1
# the goal is 23.7 mm from the far rod's surface: 25 mm is refused before any search; 20 mm
# is searched for and not found (the far rod leaves 16 mm to the block's face above it and
# the near rod 20 mm below it, both across the whole block in z)
expect_fail "clearance the goal cannot keep" 1 "closer than the clearance" -- \
    plan $SC --target goal --clearance 0.025 -o "$TMP/none"
expect_fail "clearance no path keeps" 1 "rrt: no path with 20 mm clearance" -- \
    plan $SC --target goal --clearance 0.02 -o "$TMP/none"
[ ! -e "$TMP/none/plan.json" ] && pass "no plan.json after a failure" || fail "failure wrote" "plan.json"
echo '{' >"$TMP/file"
expect_fail "-o onto a file" 1 "is not a folder" -- plan $SC --target goal -o "$TMP/file"

# bad path.csv files: refused at their line, the run's folder not made
bad_path() { # NAME TEXT CONTENT
    mkdir -p "$TMP/bad"
    printf '%b' "$3" >"$TMP/bad/path.csv"
    rm -rf "$TMP/badrun"
    expect_fail "run --plan: $1" 1 "$2" -- run $SC --plan "$TMP/bad" --steps 2 -o "$TMP/badrun"
    [ ! -e "$TMP/badrun" ] || fail "run --plan: $1" "the run's folder was made"
}
bad_path "no header" "path.csv:1: expected the header x_m,y_m,z_m" '0,0,0\n1,1,1\n'
bad_path "a NaN" "path.csv:3: a coordinate is not a finite number within 10 m" \
    'x_m,y_m,z_m\n0,0,0\nnan,0,0\n'
bad_path "two numbers" "path.csv:2: expected three numbers x_m,y_m,z_m" 'x_m,y_m,z_m\n0,0\n'
bad_path "a fourth number" "path.csv:2: expected three numbers x_m,y_m,z_m (something follows" \
    'x_m,y_m,z_m\n0,0,0,0\n0,0,1\n'
bad_path "one point" "path.csv:3: a path needs at least 2 points" 'x_m,y_m,z_m\n0,0,0\n'
bad_path "far away" "path.csv:2: a coordinate is not a finite number within 10 m" \
    'x_m,y_m,z_m\n1e9,0,0\n0,0,0\n'
bad_path "empty" "path.csv:1: empty" ''
bad_path "a NUL byte" "path.csv:3: a NUL byte" 'x_m,y_m,z_m\n0,0,0\n0,0,1\0junk'
rm -f "$TMP/bad/path.csv"
mkfifo "$TMP/bad/path.csv"
expect_fail "run --plan: a FIFO" 1 "is a FIFO (named pipe), not a plan path" -- run $SC --plan "$TMP/bad" --steps 2 -o "$TMP/badrun"
rm -f "$TMP/bad/path.csv"
expect_fail "run --plan: no path.csv" 1 "path.csv" -- run $SC --plan "$TMP/bad" --steps 2 -o "$TMP/badrun"
expect_fail "run --plan with --no-render" 2 "--no-render with --plan" -- \
    run $SC --plan "$TMP/out" --no-render

echo "$PASSED passed, $FAILED failed"
[ "$FAILED" = 0 ]
