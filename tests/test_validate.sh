#!/bin/bash
# `needlesim validate`: the built-in validation cases pass (docs/validation.md; NOT_MET below),
# the JSON has the contract's keys, and bad arguments are usage errors (exit 2) before anything
# runs.
#
# usage: tests/test_validate.sh NEEDLESIM_BINARY [1|2]
# With a group, only that half of the cases runs (meson runs the halves as two tests, side by
# side on two cores); the checks of the command itself run with group 1. Without, all of it.
# Prints one line per check; exits 0 only if every check passes.
set -u

BIN=${1:?usage: test_validate.sh NEEDLESIM_BINARY [1|2]}
GROUP=${2:-all}
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-validate.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
PASSED=0
FAILED=0

pass() {
    echo "ok    $1"
    PASSED=$((PASSED + 1))
}

fail() {
    echo "FAIL  $1: $2"
    FAILED=$((FAILED + 1))
}

GROUP1="fem-patch fem-compression fem-cantilever fem-vibration fem-inversion fem-lazy
rod-cantilever rod-buckling rod-twist rod-torsion rod-length rod-reparam friction-stick
friction-slip friction-reversal twist-friction puncture solver-agreement tg43-dose-rate
tg43-radial tg43-anisotropy tg43-geometry"
GROUP2="symmetric-straight remesh-restore remesh-substeps double-bend"
ALL="$GROUP1 $GROUP2"
case "$GROUP" in
1) CASES=$GROUP1 ;;
2) CASES=$GROUP2 ;;
*) CASES=$ALL ;;
esac
# Cases whose bar is not met yet: listed by --list and runnable, not required to pass here. Not
# a way to hide a failure: a case moves up to CASES when it passes. double-bend-entries: two
# of its seven entries put the joint 5.1 mm after the twist point (docs/validation.md).
NOT_MET="double-bend-entries"
# Passing cases run by their own meson tests (tests/meson.build: validate-cycles, ~4 min, and
# validate-steering, bevel-arc's six insertions, ~80 s), so that they run beside this one; they
# are not defined in the sanitizer build (~20 and ~8 min there), whose remeshing and steering
# are covered by remesh-restore and double-bend (both steering models) here and the unit test's
# cycles.
SEPARATE="remesh-cycles bevel-arc"

# The suite's passing cases, as JSON.
"$BIN" validate $CASES --json >"$TMP/out.json" 2>"$TMP/err"
rc=$?
cat "$TMP/out.json"
if [ $rc = 0 ]; then pass "validate --json exits 0"; else fail "validate --json exits 0" "exit $rc"; fi
for c in $CASES; do
    line=$(grep "\"name\": \"$c\"" "$TMP/out.json")
    if [ -z "$line" ]; then
        fail "$c" "missing from the output"
    elif ! echo "$line" | grep -q '"pass": true'; then
        fail "$c" "did not pass"
    else
        missing=""
        for key in name metric value reference error tolerance pass; do
            echo "$line" | grep -q "\"$key\": " || missing="$missing $key"
        done
        if [ -n "$missing" ]; then fail "$c" "keys missing:$missing"; else pass "$c passes"; fi
    fi
done
NCASES=$(echo $CASES | wc -w)
if grep -q "^  \"passed\": $NCASES,\$" "$TMP/out.json" && grep -q '^  "failed": 0$' "$TMP/out.json"; then
    pass "passed $NCASES, failed 0"
else
    fail "passed/failed counts" "$(grep -E '"(passed|failed)"' "$TMP/out.json" | tr -d '\n')"
fi
if command -v python3 >/dev/null; then
    if python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); assert len(d["cases"]) == int(sys.argv[2])' \
        "$TMP/out.json" "$NCASES" 2>"$TMP/py"; then
        pass "JSON parses"
    else
        fail "JSON parses" "$(head -1 "$TMP/py")"
    fi
fi

if [ "$GROUP" = 2 ]; then # the command's own checks run with group 1
    echo "$PASSED passed, $FAILED failed"
    [ "$FAILED" = 0 ]
    exit
fi

# One case, as a table.
"$BIN" validate fem-compression >"$TMP/out.txt" 2>"$TMP/err"
rc=$?
if [ $rc = 0 ] && grep -q '^fem-compression .* pass$' "$TMP/out.txt" &&
    [ "$(tail -1 "$TMP/out.txt")" = "1 passed, 0 failed" ]; then
    pass "one case as a table"
else
    fail "one case as a table" "exit $rc, $(tail -1 "$TMP/out.txt")"
fi

# --list names every case.
"$BIN" validate --list >"$TMP/list" 2>&1
ok=1
for c in $ALL $NOT_MET $SEPARATE; do grep -q "^$c " "$TMP/list" || ok=0; done
# ... and no case is left out of the lists (a new case must be run or named as not met).
[ "$(grep -c '^[a-z]' "$TMP/list")" = "$(echo $ALL $NOT_MET $SEPARATE | wc -w)" ] || ok=0
if [ $ok = 1 ]; then pass "--list"; else fail "--list" "$(cat "$TMP/list")"; fi

# Usage errors: exit 2, nothing run.
"$BIN" validate fem-patch no-such-case >"$TMP/out" 2>"$TMP/err"
rc=$?
if [ $rc = 2 ] && grep -q "unknown case 'no-such-case'" "$TMP/err" && ! grep -q "fem-patch" "$TMP/err"; then
    pass "unknown case: exit 2 before running"
else
    fail "unknown case: exit 2 before running" "exit $rc: $(head -2 "$TMP/err")"
fi
"$BIN" validate --bogus >"$TMP/out" 2>"$TMP/err"
rc=$?
if [ $rc = 2 ] && grep -q "unknown option '--bogus'" "$TMP/err"; then
    pass "unknown option: exit 2"
else
    fail "unknown option: exit 2" "exit $rc"
fi

echo "$PASSED passed, $FAILED failed"
[ "$FAILED" = 0 ]
