#!/bin/bash
# `meson install` gives a working program (issue 33): a copy of the source tree is configured
# (release, -Dtests=false: the program alone), built and installed with a DESTDIR under a prefix
# that does not exist, so the installed files can only be found from the binary's own location;
# the copy and its build folder are then deleted, and the installed needlesim, with no
# NEEDLESIM_* variables and from another folder, must say where it looks (`--version`), check
# the installed tutorial scenario and run it for a few steps with a finite report.
#
# usage: tests/test_install.sh SOURCE_DIR
# A full build (about 2–3 minutes on 2 cores). NS_INSTALL_JOBS sets ninja's -j (default 2).
set -u

SRC=$(cd "${1:?usage: test_install.sh SOURCE_DIR}" && pwd) || exit 1
TMP=$(mktemp -d "${TMPDIR:-/tmp}/needlesim-install.XXXXXX") || exit 1
trap 'rm -rf "$TMP"' EXIT
PREFIX=/nonexistent-needlesim-prefix/usr
STAGE=$TMP/stage
PASSED=0
FAILED=0
pass() { echo "ok    $1"; PASSED=$((PASSED + 1)); }
fail() {
    echo "FAIL  $1: $2"
    [ -s "$TMP/log" ] && tail -20 "$TMP/log" | sed 's/^/      /'
    FAILED=$((FAILED + 1))
}
finish() {
    echo "$PASSED passed, $FAILED failed"
    [ "$FAILED" -eq 0 ]
    exit
}

# 1. A copy of the tree: the files git knows (tracked, or new and not ignored), else the
#    folders the build needs.
mkdir -p "$TMP/src"
if git -C "$SRC" rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    (cd "$SRC" && git ls-files -z --cached --others --exclude-standard |
        while IFS= read -r -d '' f; do [ -e "$f" ] && printf '%s\0' "$f"; done |
        xargs -0 cp --parents -t "$TMP/src") || { fail "copy" "git ls-files | cp failed"; finish; }
else
    for f in meson.build meson_options.txt LICENSE README.md engine sim render scripts \
        scenarios assets tests; do
        cp -r "$SRC/$f" "$TMP/src/" || { fail "copy" "cp $f failed"; finish; }
    done
fi
pass "copied the source tree"

# 2. Configure, build and install the program alone.
if meson setup "$TMP/build" "$TMP/src" -Dbuildtype=release -Dtests=false \
    --prefix "$PREFIX" >"$TMP/log" 2>&1 &&
    ninja -C "$TMP/build" -j "${NS_INSTALL_JOBS:-2}" >>"$TMP/log" 2>&1 &&
    DESTDIR="$STAGE" meson install -C "$TMP/build" --quiet >>"$TMP/log" 2>&1; then
    pass "meson setup (release, -Dtests=false), ninja, meson install"
else
    fail "build and install" "see the log"
    finish
fi
if [ -e "$TMP/build/tests" ]; then
    fail "-Dtests=false" "the build made $TMP/build/tests"
else
    pass "-Dtests=false builds the program alone"
fi

# 3. The source and the build are gone; only the installation is left.
rm -rf "$TMP/src" "$TMP/build"
ROOT=$STAGE$PREFIX
BIN=$ROOT/bin/needlesim
SHARE=$ROOT/share/needlesim
for f in "$BIN" "$SHARE/scripts/needlesim.lua" "$SHARE/scripts/needlesim/actions.lua" \
    "$SHARE/scenarios/tutorial.lua" "$SHARE/assets/README.md" \
    "$ROOT/share/doc/needlesim/LICENSE"; do
    if [ -e "$f" ]; then pass "installed ${f#"$ROOT"/}"; else fail "installed" "no $f"; fi
done
[ -x "$BIN" ] || finish

# The installed program, with none of the NEEDLESIM_* overrides, from a folder unrelated to it.
mkdir -p "$TMP/elsewhere"
ns() {
    (cd "$TMP/elsewhere" &&
        env -u NEEDLESIM_SCRIPTS -u NEEDLESIM_SCENARIOS -u NEEDLESIM_ASSETS "$BIN" "$@")
}

if ns --version >"$TMP/version" 2>"$TMP/log"; then
    for what in scripts scenarios assets; do
        want="$what: $SHARE/$what (found via the binary's location"
        if grep -qF "$want" "$TMP/version"; then
            pass "--version: $what found beside the binary"
        else
            fail "--version" "no line '$want...' in: $(tr '\n' '|' <"$TMP/version")"
        fi
    done
else
    fail "--version" "exit status $?"
fi

if ns check "$SHARE/scenarios/tutorial.lua" >"$TMP/check" 2>"$TMP/log"; then
    pass "needlesim check <prefix>/share/needlesim/scenarios/tutorial.lua"
else
    fail "check tutorial.lua" "exit status $?"
fi

OUT=$TMP/out
if ns run "$SHARE/scenarios/tutorial.lua" --no-render -o "$OUT" --steps 20 --quiet \
    >/dev/null 2>"$TMP/log"; then
    if python3 - "$OUT/report.json" >"$TMP/log" 2>&1 <<'PY'; then
import json, math, sys
r = json.load(open(sys.argv[1]))
assert r["steps"] == 20, "steps %r" % r["steps"]
assert isinstance(r["state_hash"], str) and r["state_hash"], "no state_hash"
assert math.isfinite(r["needle"]["depth_m"]), "depth not finite"
PY
        pass "needlesim run tutorial.lua --steps 20: report.json with 20 steps"
    else
        fail "run tutorial.lua" "report.json"
    fi
else
    fail "run tutorial.lua" "exit status $?"
fi

finish
