# Sourced by tests/test_score.sh and tools/bench_score.sh: record_sessions DIR N FIRST_STEPS STEP
# records N tutorial sessions (two at a time) as DIR/lNN.csv with their direct runs' reports in
# DIR/dNN/report.json: trainees t1..t4 in turn, sessions s1..sN, the session k lasting
# FIRST_STEPS + k * STEP steps (so that the scores differ). Needs BIN and SRC. Returns 1 if a
# recording failed.
record_sessions() {
    local dir="$1" n="$2" first="$3" step="$4" k pids=() rc=0
    for k in $(seq 1 "$n"); do
        local id
        id=$(printf '%02d' "$k")
        "$BIN" run "$SRC/scenarios/tutorial.lua" --no-render --quiet \
            --steps $((first + (k - 1) * step)) -o "$dir/d$id" --record "$dir/l$id.csv" \
            --trainee "t$(((k - 1) % 4 + 1))" --session "s$id" 2>"$dir/rec$id.err" &
        pids+=($!)
        if [ ${#pids[@]} -ge 2 ]; then
            wait "${pids[0]}" || rc=1
            pids=("${pids[@]:1}")
        fi
    done
    for p in "${pids[@]}"; do wait "$p" || rc=1; done
    return $rc
}
