#!/bin/bash
# Determinism with stored hashes (STYLE.md: as Box2D keeps one; issue 33): each shipped scenario
# runs for the steps tests/hashes.txt gives, on 1 and on 2 threads, and its report's state_hash
# must equal the stored value; the 1- and 2-thread hashes must also equal each other (results do
# not depend on the thread count: docs/solvers.md, "Threads and determinism"). Every scenario
# in scenarios/ must have its lines.
#
# A change that moves the hashes updates tests/hashes.txt in the same commit and says why:
#   tests/test_hashes.sh build/needlesim . --update
# rewrites it (keeping each scenario's steps; a new scenario gets DEFAULT_STEPS, lines of
# scenarios that are gone are dropped) and prints what changed.
#
# usage: tests/test_hashes.sh NEEDLESIM_BINARY SOURCE_DIR [--update]
set -u

BIN=${1:?usage: test_hashes.sh NEEDLESIM_BINARY SOURCE_DIR [--update]}
SRC=$(cd "${2:?usage: test_hashes.sh NEEDLESIM_BINARY SOURCE_DIR [--update]}" && pwd) || exit 1
UPDATE=0
[ "${3:-}" = "--update" ] && UPDATE=1
FILE=$SRC/tests/hashes.txt
DEFAULT_STEPS=100
THREADS="1 2"
export NEEDLESIM_SCRIPTS=$SRC/scripts
# Waiting OpenMP threads sleep: beside other tests on 2 cores, spinning ones made a 2-thread run
# 10x slower (tools/quickstart.sh). The bits do not depend on it.
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-passive}
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-hashes.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT

# The machine the hashes belong to: the CPU and the BLAS build (CHOLMOD's factorizations, and so
# the bits, depend on the kernels OpenBLAS picks for the CPU).
machine() {
    local cpu blas
    cpu=$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo 2>/dev/null | head -1)
    blas=$("$BIN" --version 2>/dev/null | sed -n 's/^BLAS: //p')
    echo "${cpu:-unknown CPU}; ${blas:-unknown BLAS}"
}

# The steps for each scenario: from hashes.txt, else DEFAULT_STEPS.
steps_of() {
    local s
    s=$(awk -v sc="$1" '$1 == sc { print $2; exit }' "$FILE" 2>/dev/null)
    echo "${s:-$DEFAULT_STEPS}"
}

# hash SCENARIO STEPS THREADS: prints the state hash, or ERROR:<reason>.
hash() {
    local out=$TMP/$1-$3
    if ! "$BIN" run "$SRC/scenarios/$1" --no-render --steps "$2" --threads "$3" -o "$out" \
        --quiet >"$TMP/stdout" 2>"$TMP/stderr"; then
        echo "ERROR:exit-$?:$(head -1 "$TMP/stderr" | tr ' ' '_')"
        return
    fi
    python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["state_hash"])' \
        "$out/report.json" 2>/dev/null || echo "ERROR:no-state_hash"
}

PASSED=0
FAILED=0
DIFF=$TMP/diff
: >"$DIFF"
: >"$TMP/new"
for path in "$SRC"/scenarios/*.lua; do
    sc=${path##*/}
    n=$(steps_of "$sc")
    first=""
    for t in $THREADS; do
        start=$(date +%s.%N)
        h=$(hash "$sc" "$n" "$t")
        secs=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
        printf '%-24s %5s %3s %s\n' "$sc" "$n" "$t" "$h" >>"$TMP/new"
        want=$(awk -v sc="$sc" -v n="$n" -v t="$t" '$1 == sc && $2 == n && $3 == t { print $4 }' \
            "$FILE" 2>/dev/null)
        case "$h" in ERROR:*)
            echo "FAIL  $sc, $n steps, $t thread(s): the run failed ($h)"
            FAILED=$((FAILED + 1))
            continue
            ;;
        esac
        if [ -z "$first" ]; then
            first=$h
        elif [ "$h" != "$first" ]; then
            echo "FAIL  $sc, $n steps: $t threads give $h, 1 thread $first (must be equal)"
            FAILED=$((FAILED + 1))
            continue
        fi
        if [ "$UPDATE" -eq 1 ]; then
            [ "$h" = "$want" ] || echo "$sc $n $t: ${want:-(none)} -> $h" >>"$DIFF"
            echo "ok    $sc, $n steps, $t thread(s): $h (${secs} s)"
            PASSED=$((PASSED + 1))
        elif [ -z "$want" ]; then
            echo "FAIL  $sc, $n steps, $t thread(s): no stored hash in tests/hashes.txt (got $h)"
            echo "$sc $n $t: (none) -> $h" >>"$DIFF"
            FAILED=$((FAILED + 1))
        elif [ "$h" != "$want" ]; then
            echo "FAIL  $sc, $n steps, $t thread(s): state_hash $h, stored $want"
            echo "$sc $n $t: $want -> $h" >>"$DIFF"
            FAILED=$((FAILED + 1))
        else
            echo "ok    $sc, $n steps, $t thread(s): $h (${secs} s)"
            PASSED=$((PASSED + 1))
        fi
    done
done
# Stored lines of scenarios that are no longer shipped.
if [ -f "$FILE" ]; then
    for sc in $(awk '!/^#/ && NF { print $1 }' "$FILE" | sort -u); do
        if [ ! -f "$SRC/scenarios/$sc" ]; then
            echo "$sc: stored, but no scenarios/$sc" >>"$DIFF"
            [ "$UPDATE" -eq 1 ] || { echo "FAIL  $sc: in tests/hashes.txt, not in scenarios/"; FAILED=$((FAILED + 1)); }
        fi
    done
fi

if [ "$UPDATE" -eq 1 ]; then
    if [ "$FAILED" -ne 0 ]; then
        echo "not updated: $FAILED run(s) failed or differed between thread counts"
        exit 1
    fi
    {
        echo "# State hashes of the shipped scenarios (tests/test_hashes.sh): each runs"
        echo "#   needlesim run scenarios/SCENARIO --no-render --steps STEPS --threads THREADS --quiet"
        echo "# and report.json's state_hash must be HASH, the same on every thread count."
        echo "# The bits depend on the machine: they hold on the CPU and BLAS below (CHOLMOD's"
        echo "# factorizations run OpenBLAS's kernels for the CPU it finds), not elsewhere; the"
        echo "# release and debugoptimized builds give the same bits (-ffp-contract=off)."
        echo "# A change that moves them updates this file in the same commit and says why:"
        echo "#   tests/test_hashes.sh build/needlesim . --update"
        echo "# machine: $(machine)"
        echo "# scenario                steps threads hash"
        cat "$TMP/new"
    } >"$FILE"
    if [ -s "$DIFF" ]; then
        echo "tests/hashes.txt updated; changed:"
        sed 's/^/  /' "$DIFF"
    else
        echo "tests/hashes.txt rewritten; no hash changed"
    fi
    exit 0
fi

echo "$PASSED passed, $FAILED failed"
if [ "$FAILED" -ne 0 ]; then
    if [ -s "$DIFF" ]; then
        echo "differences (scenario steps threads: stored -> now):"
        sed 's/^/  /' "$DIFF"
    fi
    recorded=$(sed -n 's/^# machine: //p' "$FILE" 2>/dev/null)
    now=$(machine)
    if [ "$recorded" != "$now" ]; then
        echo "note: the hashes were recorded on \"$recorded\"; this machine is \"$now\":"
        echo "      stored hashes hold only on the machine type and BLAS they were made on"
    fi
    echo "If the change is meant (say why in the commit), regenerate with:"
    echo "  tests/test_hashes.sh $BIN $SRC --update"
    exit 1
fi
exit 0
