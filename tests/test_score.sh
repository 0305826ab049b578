#!/bin/bash
# `needlesim score` end to end (docs/scoring.md, issue 37).
#
# local (default): 12 tutorial sessions recorded by script (4 trainees, 3 sessions each, of
# different lengths), a corrupt log and a log recorded against another scenario file, scored
# with --jobs 2: one row per log in the order given, the two bad logs as error rows with their
# messages, every other row's state_hash that of the direct run, the cohort report written
# (cohort.json's keys, a self-contained cohort.html, a PNG); then a batch killed (SIGKILL)
# after its first sessions resumes: only the unscored sessions are replayed and scores.csv is
# the same; usage errors exit 2; an OUT/sessions that is a link out of OUT is refused.
#
# slurm: 12 shorter sessions scored with --jobs 2 and through Slurm (`--slurm --array-chunk 5`,
# a one-node Slurm: tools/slurm-local.sh up, SLURM_CONF set); scores.csv and cohort.json are
# identical. Without a Slurm that answers it is skipped (exit 77), unless
# NEEDLESIM_SLURM_REQUIRED=1 (.ci/run), when it fails.
#
# usage: tests/test_score.sh NEEDLESIM_BINARY SOURCE_DIR [local|slurm]
set -u
BIN=${1:?usage: test_score.sh NEEDLESIM_BINARY SOURCE_DIR [local|slurm]}
SRC=${2:?usage: test_score.sh NEEDLESIM_BINARY SOURCE_DIR [local|slurm]}
PART=${3:-local}
export OPENBLAS_NUM_THREADS=1
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-score.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
PASSED=0
FAILED=0
pass() { echo "ok    $1"; PASSED=$((PASSED + 1)); }
fail() { echo "FAIL  $1: $2"; FAILED=$((FAILED + 1)); }
finish() {
    echo "$PASSED passed, $FAILED failed"
    [ "$FAILED" = 0 ]
    exit $?
}
. "$SRC/tests/score_sessions.sh"
cd "$TMP" || exit 1

if [ "$PART" = slurm ]; then
    if ! command -v sbatch >/dev/null || ! sinfo -h >/dev/null 2>&1; then
        if [ "${NEEDLESIM_SLURM_REQUIRED:-0}" = 1 ]; then
            fail "slurm" "no Slurm answers (SLURM_CONF=${SLURM_CONF:-unset}): tools/slurm-local.sh up"
            finish
        fi
        echo "skipped: no Slurm (bash tools/slurm-local.sh up; export SLURM_CONF=...)"
        exit 77
    fi
    mkdir s && record_sessions s 12 30 4 && pass "12 sessions recorded" || fail "recording" "$(cat s/rec*.err | head -2)"
    printf 'not a log\n' >s/bad.csv
    logs=(s/l0{1..6}.csv s/bad.csv s/l0{7..9}.csv s/l1{0..2}.csv)
    "$BIN" score "${logs[@]}" -o local --jobs 2 2>local.err
    rc1=$?
    "$BIN" score "${logs[@]}" -o viaslurm --slurm --array-chunk 5 --jobs 1 2>slurm.err
    rc2=$?
    if [ $rc1 = 0 ] && [ $rc2 = 0 ]; then pass "scored locally and through Slurm"; else fail "score" "exit $rc1 / $rc2: $(tail -2 local.err slurm.err)"; fi
    if [ -s local/scores.csv ] && cmp -s local/scores.csv viaslurm/scores.csv; then
        pass "scores.csv identical, row for row ($(($(wc -l <local/scores.csv) - 1)) rows)"
    else
        fail "scores.csv differ" "$(diff local/scores.csv viaslurm/scores.csv | head -4)"
    fi
    if cmp -s local/cohort.json viaslurm/cohort.json; then pass "cohort.json identical"; else fail "cohort.json differ" "$(diff local/cohort.json viaslurm/cohort.json | head -4)"; fi
    n=$(ls viaslurm/slurm/rows-*.csv 2>/dev/null | wc -l)
    if [ "$n" = 3 ]; then pass "three array tasks, each with its rows file"; else fail "array tasks" "$n rows files"; fi
    finish
fi

# ---- local ----
mkdir s && record_sessions s 12 40 5 && pass "12 sessions recorded" || fail "recording" "$(cat s/rec*.err | head -2)"
# A corrupt log: a number that is not one, at line 20.
sed '20s/^\([^,]*\),[^,]*,/\1,zz,/' s/l01.csv >s/corrupt.csv
# A log recorded against another scenario file (an edited copy of the tutorial, same name).
mkdir other && { echo "-- an edited copy"; cat "$SRC/scenarios/tutorial.lua"; } >other/tutorial.lua
"$BIN" run other/tutorial.lua --no-render --quiet --steps 20 -o other/d --record s/other.csv \
    --trainee t9 --session x1 2>/dev/null || fail "recording against the copy" "exit $?"
logs=(s/l0{1..6}.csv s/corrupt.csv s/l0{7..9}.csv s/other.csv s/l1{0..2}.csv)
"$BIN" score "${logs[@]}" -o out1 --jobs 2 2>out1.err
rc=$?
if [ $rc = 0 ] && grep -q "14 sessions: 14 replayed, 0 already scored, 2 errors" out1.err; then
    pass "score --jobs 2: 14 logs replayed, 2 of them errors"
else
    fail "score --jobs 2" "exit $rc: $(tail -2 out1.err)"
fi
python3 - "$SRC" "${logs[@]}" <<'PY' >py.out 2>&1
import csv, json, sys
logs = sys.argv[2:]
rows = list(csv.DictReader(open("out1/scores.csv")))
cols = ("log,trainee,session,scenario,scenario_hash,status,error,score,targets,targets_hit,"
        "target_error_mm_max,target_errors_mm,obstacles_violated,obstacles_entered,sim_time_s,"
        "steps,warnings_nan,warnings_inverted,warnings_unconverged,warnings_lcp_unresolved,"
        "state_hash").split(",")
assert list(rows[0].keys()) == cols, list(rows[0].keys())
assert [r["log"] for r in rows] == logs, "order"
for r in rows:
    name = r["log"].split("/")[-1]
    if name in ("corrupt.csv", "other.csv"):
        assert r["status"] == "error" and r["score"] == "" and r["state_hash"] == "", r
        continue
    assert r["status"] == "ok" and r["error"] == "", r
    k = name[1:3]
    rep = json.load(open("s/d%s/report.json" % k))
    assert r["state_hash"] == rep["state_hash"], (name, r["state_hash"], rep["state_hash"])
    assert abs(float(r["score"]) - rep["score"]["total"]) < 1e-4, name
    assert int(r["steps"]) == rep["steps"] and r["scenario"] == "tutorial"
    assert r["trainee"] == "t%d" % ((int(k) - 1) % 4 + 1) and r["session"] == "s" + k, r
c = [r for r in rows if r["log"].endswith("corrupt.csv")][0]
assert c["error"].startswith("needlesim: s/corrupt.csv:24: v_insert_m_s must be a finite number") or \
    "corrupt.csv:" in c["error"] and "finite number" in c["error"], c["error"]
o = [r for r in rows if r["log"].endswith("other.csv")][0]
assert "recorded against scenario 'tutorial' (hash" in o["error"] and "not 'tutorial' (hash" in o["error"], o["error"]
assert o["trainee"] == "t9" and o["session"] == "x1"
cj = json.load(open("out1/cohort.json"))
assert cj["sessions"] == 14 and cj["ok"] == 12 and cj["errors"] == 2, cj
assert [t["trainee"] for t in cj["trainees"]] == ["t1", "t2", "t3", "t4", "t9"]
assert len(cj["trainees"][0]["sessions"]) == 4  # with the corrupt copy of l01
assert cj["scenarios"][0]["scenario"] == "tutorial" and cj["scenarios"][0]["scored"] == 12
assert cj["review"][0]["log"].endswith("corrupt.csv") and cj["review"][1]["log"].endswith("other.csv")
html = open("out1/cohort.html").read()
assert "<svg" in html and "http" not in html and "<script" not in html
assert open("out1/cohort.png", "rb").read(8) == b"\x89PNG\r\n\x1a\n"
print("scores %s" % " ".join(r["score"] for r in rows if r["status"] == "ok"))
PY
if [ $? = 0 ]; then pass "rows in order, error rows, state hashes of the direct runs, cohort report ($(tail -1 py.out))"; else fail "rows" "$(tail -3 py.out)"; fi

# A killed batch resumes: only the unscored sessions are replayed; the same scores.csv.
"$BIN" score "${logs[@]}" -o out2 --jobs 1 2>kill.err &
pid=$!
for _ in $(seq 1 600); do
    [ "$(ls out2/sessions/*/scored 2>/dev/null | wc -l)" -ge 3 ] && break
    sleep 0.2
done
kill -KILL $pid
wait $pid 2>/dev/null
done_before=$(ls out2/sessions/*/scored 2>/dev/null | wc -l)
if [ ! -e out2/scores.csv ] && [ "$done_before" -ge 3 ] && [ "$done_before" -lt 12 ]; then
    pass "killed after $done_before sessions: no scores.csv"
else
    fail "kill" "$done_before scored, scores.csv $(ls out2/scores.csv 2>&1)"
fi
# The killed batch's replays get SIGTERM with their parent and clean up their own part files,
# whose names a resumed replay of the same session reuses: wait until they have exited (a
# second after a kill was not always enough on a loaded machine). Their command lines name
# out2/sessions/ (read from /proc: no procps needed; the bracket keeps grep from finding itself).
for _ in $(seq 1 300); do
    grep -qas -- "out2/session[s]/" /proc/[0-9]*/cmdline 2>/dev/null || break
    sleep 0.2
done
"$BIN" score "${logs[@]}" -o out2 --jobs 2 2>resume.err
rc=$?
if [ $rc = 0 ] && grep -q "14 sessions: $((14 - done_before)) replayed, $done_before already scored, 2 errors" resume.err; then
    pass "resumed: $((14 - done_before)) replayed (the 2 error rows again), $done_before already scored"
else
    fail "resume" "exit $rc: $(tail -1 resume.err)"
fi
if cmp -s out1/scores.csv out2/scores.csv; then pass "the resumed batch's scores.csv is the uninterrupted one's"; else fail "resumed scores.csv" "$(diff out1/scores.csv out2/scores.csv | head -3)"; fi
if [ -z "$(find out2 -name '*.part' -o -name '.*.err')" ]; then pass "no temporary files left"; else fail "temporary files" "$(find out2 -name '*.part' -o -name '.*.err')"; fi
"$BIN" score "${logs[@]}" -o out2 --jobs 2 2>again.err
if grep -q "14 sessions: 2 replayed, 12 already scored" again.err; then pass "a third run replays only the two that failed"; else fail "third run" "$(tail -1 again.err)"; fi

# Usage errors and output confinement.
usage() { # name, expected exit, args...
    local name="$1" want="$2"
    shift 2
    "$BIN" score "$@" >/dev/null 2>u.err
    local rc=$?
    if [ $rc = "$want" ] && [ "$(wc -l <u.err)" = 1 ]; then pass "$name: exit $want, one line"; else fail "$name" "exit $rc: $(head -2 u.err)"; fi
}
usage "no -o" 2 s/l01.csv
usage "--jobs 0" 2 s/l01.csv -o u --jobs 0
usage "no logs" 2 -o u
usage "--array-chunk without --slurm" 2 s/l01.csv -o u --array-chunk 3
touch afile
usage "-o a file" 1 s/l01.csv -o afile
mkdir -p linked outside && ln -s "$TMP/outside" linked/sessions
usage "OUT/sessions a link out of OUT" 1 s/l01.csv -o linked
if [ -z "$(ls outside)" ]; then pass "nothing written through the link"; else fail "link" "$(ls outside)"; fi
finish
