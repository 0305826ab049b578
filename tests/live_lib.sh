# Sourced by tests/test_live.sh and tests/test_browser.sh: a `needlesim live` session started in
# the background, waited for, and its recorded log replayed. Expects BIN, TMP and PY; the ids
# of the sessions started go to PIDS (the caller's trap kills them: stop_sessions).

PIDS=()

# start NAME ARGS...: starts a session in the background (stdout and stderr in $TMP/NAME.out and
# .err); its URL in $URL (empty on failure), its id in $PID.
start() {
    local name=$1
    shift
    "$BIN" live "$@" >"$TMP/$name.out" 2>"$TMP/$name.err" &
    PID=$!
    PIDS+=("$PID")
    URL=""
    for _ in $(seq 1 600); do # liveness: up to 120 s to build the scenario and listen
        URL=$(sed -n '1s/^needlesim live: open //p' "$TMP/$name.out")
        [ -n "$URL" ] && return 0
        kill -0 "$PID" 2>/dev/null || return 1
        sleep 0.2
    done
    return 1
}

# stop_sessions: kills every session started (for the caller's trap).
stop_sessions() {
    for p in "${PIDS[@]}"; do
        kill -KILL "$p" 2>/dev/null
    done
}

# wait_exit PID SECONDS: the process's exit status, or 124 after SECONDS (then it is killed).
wait_exit() {
    local pid=$1 n=$(($2 * 5))
    for _ in $(seq 1 "$n"); do
        if ! kill -0 "$pid" 2>/dev/null; then
            wait "$pid"
            return $?
        fi
        sleep 0.2
    done
    kill -KILL "$pid" 2>/dev/null
    return 124
}

# replay_same SCENARIO SESSION_DIR LOG NAME: `needlesim run SCENARIO --replay LOG` into
# $TMP/NAME; 0 when its report.json has SESSION_DIR/report.json's state hash, score and steps
# (else the difference, or the run's error, on stdout).
replay_same() {
    "$BIN" run "$1" --replay "$3" -o "$TMP/$4" --no-render --quiet 2>"$TMP/$4.err" || {
        tail -2 "$TMP/$4.err"
        return 1
    }
    "$PY" - "$2/report.json" "$TMP/$4/report.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
for what, x, y in (("state hash", a["state_hash"], b["state_hash"]),
                   ("score", a["score"]["total"], b["score"]["total"]),
                   ("steps", a["steps"], b["steps"])):
    if x != y:
        print("%s: the session's %s, the replay's %s" % (what, x, y))
        sys.exit(1)
print("state hash %s, score %s, %d steps" % (a["state_hash"], a["score"]["total"], a["steps"]))
PY
}
