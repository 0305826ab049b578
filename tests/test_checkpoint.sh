#!/bin/bash
# Checkpoints (docs/checkpoints.md): `--checkpoint-at T FILE` and `--resume FILE`.
#
# tutorial (default): a run that writes a checkpoint ends in the same state as one that does
# not; the run resumed from it ends in that state too, with the same trajectory, score and
# recorded control log as the uninterrupted run; a resumed run can write a checkpoint of its
# own and that one resumes to the same end; a replayed log's run checkpoints and resumes; a
# damaged, truncated or foreign checkpoint, another scenario, other --set values, a time past
# the run's end and paths that would overwrite the run's inputs are refused with one line and
# nothing written.
#
# brachytherapy: the same round trip on the brachytherapy scenario, checkpointed at t = 10 s
# (the second needle going in, two seeds released) and resumed to step 1100.
#
# usage: tests/test_checkpoint.sh NEEDLESIM_BINARY SOURCE_DIR [tutorial|brachytherapy]
set -u

BIN=${1:?usage: test_checkpoint.sh NEEDLESIM_BINARY SOURCE_DIR [PART]}
SRC=$(cd "${2:?usage: test_checkpoint.sh NEEDLESIM_BINARY SOURCE_DIR [PART]}" && pwd) || exit 1
PART=${3:-tutorial}
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-checkpoint.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
export NEEDLESIM_SCRIPTS=$SRC/scripts
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-passive}
PASSED=0
FAILED=0
pass() { echo "ok    $1"; PASSED=$((PASSED + 1)); }
fail() { echo "FAIL  $1: $2"; FAILED=$((FAILED + 1)); }

# key DIR KEY: a top-level value of DIR/report.json (JSON), or "missing".
key() {
    python3 -c 'import json,sys; print(json.dumps(json.load(open(sys.argv[1]))[sys.argv[2]]))' \
        "$1/report.json" "$2" 2>/dev/null || echo missing
}

# run NAME ARGS...: needlesim run with -o $TMP/NAME --no-render --quiet; stdout and stderr
# to $TMP/NAME.out and $TMP/NAME.err; returns its exit status.
run() {
    local name=$1
    shift
    "$BIN" run --no-render --quiet -o "$TMP/$name" "$@" >"$TMP/$name.out" 2>"$TMP/$name.err"
}

# same NAME A B: the resumed run B ended as the uninterrupted A (hash, steps, score, targets,
# seeds, events, trajectory).
same() {
    local what=$1 a=$2 b=$3 k bad=""
    for k in state_hash steps score targets seeds events obstacles; do
        [ "$(key "$TMP/$a" $k)" = "$(key "$TMP/$b" $k)" ] || bad="$bad $k"
    done
    cmp -s "$TMP/$a/trajectory.csv" "$TMP/$b/trajectory.csv" || bad="$bad trajectory.csv"
    if [ -z "$bad" ] && [ "$(key "$TMP/$a" state_hash)" != missing ]; then
        pass "$what: state hash $(key "$TMP/$a" state_hash), score, seeds and trajectory equal"
    else
        fail "$what" "differs in:$bad ($(head -c 300 "$TMP/$b.err"))"
    fi
}

# refused NAME CODE WHAT ARGS...: exits CODE with one line on stderr naming WHAT, and writes
# neither a report nor FILE $TMP/NAME.ck.
refused() {
    local name=$1 code=$2 what=$3
    shift 3
    run "$name" "$@"
    local rc=$?
    local lines
    lines=$(wc -l <"$TMP/$name.err")
    if [ "$rc" -eq "$code" ] && [ "$lines" -eq 1 ] && grep -q -- "$what" "$TMP/$name.err" &&
        [ ! -e "$TMP/$name/report.json" ] && [ ! -e "$TMP/$name.ck" ] &&
        [ -z "$(find "$TMP" -name '*.part')" ]; then
        pass "$name refused ($rc): $(cat "$TMP/$name.err")"
    else
        fail "$name" "exit $rc, $lines lines: $(head -c 300 "$TMP/$name.err")"
    fi
}

if [ "$PART" = brachytherapy ]; then
    SC=$SRC/scenarios/brachytherapy.lua
    run A "$SC" --steps 1100 || fail "brachytherapy" "$(cat "$TMP/A.err")"
    run B "$SC" --steps 1100 --checkpoint-at 10 "$TMP/b.ck" || fail "checkpoint" "$(cat "$TMP/B.err")"
    same "brachytherapy with a checkpoint at 10 s" A B
    seeds=$(python3 -c 'import json,sys; r=json.load(open(sys.argv[1])); print(sum(1 for s in r["seeds"] if s["released_s"] <= 10))' "$TMP/B/report.json" 2>/dev/null)
    if [ "${seeds:-0}" -ge 2 ]; then pass "seeds released before the checkpoint: $seeds"; else fail "seeds" "${seeds:-none} released before 10 s"; fi
    run C "$SC" --resume "$TMP/b.ck" || fail "resume" "$(cat "$TMP/C.err")"
    same "brachytherapy resumed at 10 s" A C
    echo "$PASSED passed, $FAILED failed"
    [ "$FAILED" -eq 0 ]
    exit
fi

SC=$SRC/scenarios/tutorial.lua
run A "$SC" --record "$TMP/a.csv" || fail "tutorial" "$(cat "$TMP/A.err")"
run B "$SC" --checkpoint-at 1.0 "$TMP/b.ck" || fail "checkpoint" "$(cat "$TMP/B.err")"
same "a checkpoint written at 1 s changes nothing" A B
[ -s "$TMP/b.ck" ] && pass "checkpoint written ($(stat -c %s "$TMP/b.ck") bytes)" || fail "checkpoint" "no file"
run C "$SC" --resume "$TMP/b.ck" --record "$TMP/c.csv" || fail "resume" "$(cat "$TMP/C.err")"
same "resumed from 1 s" A C
if cmp -s "$TMP/a.csv" "$TMP/c.csv"; then pass "the resumed run's control log is the uninterrupted run's"; else fail "record" "$(diff "$TMP/a.csv" "$TMP/c.csv" | head -5)"; fi
# A checkpoint of a resumed run.
run D "$SC" --resume "$TMP/b.ck" --checkpoint-at 1.5 "$TMP/d.ck" || fail "resume+checkpoint" "$(cat "$TMP/D.err")"
same "resumed, checkpointed again at 1.5 s" A D
run E "$SC" --resume "$TMP/d.ck" || fail "second resume" "$(cat "$TMP/E.err")"
same "resumed from the second checkpoint" A E
# A replayed log checkpointed and resumed.
run F "$SC" --replay "$TMP/a.csv" --checkpoint-at 0.5 "$TMP/f.ck" || fail "replay+checkpoint" "$(cat "$TMP/F.err")"
run G "$SC" --replay "$TMP/a.csv" --resume "$TMP/f.ck" || fail "replay resume" "$(cat "$TMP/G.err")"
same "a replayed log resumed from 0.5 s" A G

# A second needle through a tilted entry (act.next_needle), checkpointed while it goes in, with
# a --set the resumed run takes from the checkpoint and writes into a checkpoint of its own.
TN=$SRC/tests/data/checkpoint/two_needles.lua
run N1 "$TN" --set tissue.refine=1 || fail "two needles" "$(cat "$TMP/N1.err")"
run N2 "$TN" --set tissue.refine=1 --checkpoint-at 1.8 "$TMP/n.ck" || fail "two needles checkpoint" "$(cat "$TMP/N2.err")"
run N3 "$TN" --resume "$TMP/n.ck" --checkpoint-at 2.0 "$TMP/n2.ck" || fail "two needles resume" "$(cat "$TMP/N3.err")"
same "a tilted second needle resumed at 1.8 s" N1 N3
run N4 "$TN" --resume "$TMP/n2.ck" || fail "two needles second resume" "$(cat "$TMP/N4.err")"
same "... and from its own checkpoint at 2 s (the --set carried)" N1 N4
if [ "$(key "$TMP/N4" sets)" = '["tissue.refine=1"]' ]; then pass "the resumed run's report has the checkpoint's --set"; else fail "sets" "$(key "$TMP/N4" sets)"; fi

# Refusals.
cp "$TMP/b.ck" "$TMP/input-damaged.ck"
size=$(stat -c %s "$TMP/input-damaged.ck")
printf '\x5a' | dd of="$TMP/input-damaged.ck" bs=1 seek=$((size / 2)) conv=notrunc status=none
refused damaged 1 "damaged\|bad array" "$SC" --resume "$TMP/input-damaged.ck"
head -c $((size - 100)) "$TMP/b.ck" >"$TMP/short.ck"
refused truncated 1 "truncated\|bad array" "$SC" --resume "$TMP/short.ck"
refused foreign 1 "not a needlesim checkpoint" "$SC" --resume "$SRC/scenarios/tutorial.lua"
refused other-scenario 1 "another scenario" "$SRC/scenarios/two_cylinders.lua" --resume "$TMP/b.ck"
refused other-set 1 "another --set" "$SC" --resume "$TMP/b.ck" --set dt=0.005
refused other-solver 1 "another --solver" "$SC" --resume "$TMP/b.ck" --solver paper
refused past-end 1 "before --checkpoint-at" "$SC" --checkpoint-at 100 "$TMP/past-end.ck"
refused same-file 2 "same file" "$SC" --resume "$TMP/b.ck" --checkpoint-at 1.5 "$TMP/b.ck"
cp "$SC" "$TMP/copy.lua"
refused onto-input 2 "the run's own input" "$TMP/copy.lua" --checkpoint-at 1 "$TMP/copy.lua"
refused bad-time 2 "expected a time" "$SC" --checkpoint-at -1 "$TMP/bad-time.ck"
refused flag-as-file 2 "expected a file" "$SC" --checkpoint-at 1 --quiet
refused folder 2 "not a regular file" "$SC" --checkpoint-at 1 "$TMP"
refused no-folder 2 "folder does not exist" "$SC" --checkpoint-at 1 "$TMP/none/x.ck"
refused not-after 1 "not after" "$SC" --resume "$TMP/b.ck" --checkpoint-at 0.5 "$TMP/not-after.ck"

echo "$PASSED passed, $FAILED failed"
[ "$FAILED" -eq 0 ]
