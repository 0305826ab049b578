#!/bin/bash
# `needlesim live` from a real browser (docs/live.md): Debian's Chromium, headless, driven over
# the DevTools protocol by tests/live_browser.py (Python's standard library only) loads the
# page, sees frames arrive, holds ArrowUp for 2 s, presses Space, sees the HUD's depth grow and
# clicks End; the session exits 0 with its outputs, and `needlesim run --replay` of its recorded
# log gives the same state hash, score and steps. The server and Chromium are stopped by the
# test (trap), whatever happens.
#
# With NEEDLESIM_SCREENSHOTS=DIR the browser saves PNGs of the page there; docs/img/live-*.png
# come from
#   NEEDLESIM_SCREENSHOTS=docs/img tests/test_browser.sh build/needlesim .
#
# usage: tests/test_browser.sh NEEDLESIM_BINARY SOURCE_DIR
set -u

BIN=${1:?usage: test_browser.sh NEEDLESIM_BINARY SOURCE_DIR}
SRC=${2:?usage: test_browser.sh NEEDLESIM_BINARY SOURCE_DIR}
PY=/usr/bin/python3
SHOTS=${NEEDLESIM_SCREENSHOTS:-}
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-browser.XXXXXX") || exit 1
. "$SRC/tests/live_lib.sh"
cleanup() {
    stop_sessions
    # Chromium's process group, if the driver could not close it itself
    [ -s "$TMP/chromium.pgid" ] && kill -KILL -- "-$(cat "$TMP/chromium.pgid")" 2>/dev/null
    rm -rf "$TMP"
}
trap cleanup EXIT
trap 'exit 143' TERM
trap 'exit 130' INT
PASSED=0
FAILED=0
pass() { echo "ok    $1"; PASSED=$((PASSED + 1)); }
fail() { echo "FAIL  $1: $2"; FAILED=$((FAILED + 1)); }
finish() {
    echo "$PASSED passed, $FAILED failed"
    [ "$FAILED" -eq 0 ]
    exit
}

if command -v chromium >/dev/null; then
    pass "chromium: $(chromium --version 2>/dev/null | head -1)"
else
    fail "chromium" "not installed (tools/quickstart.sh test installs it)"
    finish
fi
if [ -n "$SHOTS" ]; then
    mkdir -p "$SHOTS" && SHOTS=$(cd "$SHOTS" && pwd) || { fail "screenshots" "$SHOTS"; finish; }
fi

# ---- the session, at the default size, driven from the browser ----
OUT="$TMP/session"
if ! start session "$SRC/scenarios/tutorial.lua" --port 0 -o "$OUT"; then
    fail "session: start" "$(tail -3 "$TMP/session.err")"
    finish
fi
pass "session: listening at $URL"

"$PY" "$SRC/tests/live_browser.py" "$URL" "$TMP" ${SHOTS:+"$SHOTS"} 2>&1 | tee "$TMP/browser.out"
rc=${PIPESTATUS[0]}
PASSED=$((PASSED + $(grep -c '^ok ' "$TMP/browser.out")))
FAILED=$((FAILED + $(grep -c '^FAIL ' "$TMP/browser.out")))
if [ $rc -ne 0 ] && ! grep -q '^FAIL ' "$TMP/browser.out"; then
    fail "browser" "the driver exited $rc"
fi
if [ $rc -ne 0 ]; then
    echo "--- chromium's stderr (last lines)"
    grep -v 'dbus' "$TMP/chromium.log" | tail -5
    kill -TERM "$PID" # the page did not end the session
fi

wait_exit "$PID" 120
rc=$?
[ $rc -eq 0 ] && pass "session: exit 0" ||
    fail "session: exit" "$rc: $(tail -3 "$TMP/session.err")"
for f in report.json controls.csv; do
    [ -s "$OUT/$f" ] && pass "session: $f written" || fail "session: $f" "missing"
done
if "$PY" - "$OUT/report.json" <<'PY'; then
import json, sys
r = json.load(open(sys.argv[1]))
assert r["live"]["ended_by"] == "client", r["live"]["ended_by"]
assert r["live"]["frames"] >= 5, r["live"]["frames"]
assert r["needle"]["depth_m"] > 0, r["needle"]["depth_m"]
PY
    pass "session: ended by the page, frames sent, the needle inserted"
else
    fail "session: report.json" "not ended by the page, or no frames, or no insertion"
fi

# ---- the replay of the recorded log: the same state hash, score and steps ----
if r=$(replay_same "$SRC/scenarios/tutorial.lua" "$OUT" "$OUT/controls.csv" replay); then
    pass "replay: the same state hash, score and steps ($r)"
else
    fail "replay" "$r"
fi

finish
