#!/usr/bin/env bash
# The throughput of `needlesim score` with --jobs 1 and --jobs 2 (docs/scoring.md; issue 37's
# bar: --jobs 2 at >= 1.8x the rate of --jobs 1, medians over the same 12 sessions).
#
#   bash tools/bench_score.sh [BUILD_DIR] [REPEATS] [STEPS] [KEEP_DIR]
#
# Records 12 tutorial sessions (STEPS + 5 k steps for session k, default STEPS 130: most of the
# tutorial's insertion), then scores them REPEATS times (default 3) with each setting, in turn,
# each time into a fresh OUT (nothing resumed), and prints each time, the medians, the
# sessions per second and the ratio, and the CPU time (user + system, of score and its
# replays): on a machine shared with other work the wall-time ratio says how many cores were
# free, the CPU time what running two at once costs. With KEEP_DIR, the last OUT is copied there (the cohort
# report of docs/scoring.md). A benchmark: it asserts nothing.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD="${1:-$ROOT/build}"
REPEATS="${2:-3}"
FIRST="${3:-130}"
KEEP="${4:-}"
BIN="$BUILD/needlesim"
SRC="$ROOT"
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-bench-score.XXXXXX")
trap 'rm -rf "$TMP"' EXIT
. "$ROOT/tests/score_sessions.sh"
mkdir "$TMP/s"
record_sessions "$TMP/s" 12 "$FIRST" 5
logs=("$TMP"/s/l*.csv)
declare -a t1 t2 c1 c2
for r in $(seq 1 "$REPEATS"); do
    for j in 1 2; do
        rm -rf "$TMP/out"
        # wall time, and the CPU time of score and its replays (user + system)
        /usr/bin/time -f "%e %U %S" -o "$TMP/time" "$BIN" score "${logs[@]}" -o "$TMP/out" --jobs $j --quiet
        read -r w u sy <"$TMP/time"
        cpu=$(echo "$u + $sy" | bc)
        echo "repeat $r, --jobs $j: $w s wall, $cpu s CPU ($(echo "scale=2; $cpu / 12" | bc) s a session); load $(cut -d' ' -f1 /proc/loadavg)"
        if [ $j = 1 ]; then t1+=("$w"); c1+=("$cpu"); else t2+=("$w"); c2+=("$cpu"); fi
    done
done
if [ -n "$KEEP" ]; then mkdir -p "$KEEP" && cp -r "$TMP/out/." "$KEEP/"; fi
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }
m1=$(median "${t1[@]}")
m2=$(median "${t2[@]}")
echo "machine: $(nproc --all) cores, load $(cut -d' ' -f1-3 /proc/loadavg) (others' processes count too)"
echo "CPU: --jobs 1 median $(median "${c1[@]}") s, --jobs 2 median $(median "${c2[@]}") s (12 sessions)"
awk -v a="$m1" -v b="$m2" 'BEGIN {
    printf "12 sessions: --jobs 1 median %.2f s (%.3f sessions/s), --jobs 2 median %.2f s (%.3f sessions/s): %.2fx\n",
        a, 12 / a, b, 12 / b, a / b }'
