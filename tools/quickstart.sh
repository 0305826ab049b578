#!/usr/bin/env bash
# needlesim quick start: install what is missing (Debian 12, as root), build, then either run
# the main job or every test.
#
#   bash tools/quickstart.sh          # set up, build, run the brachytherapy scenario
#   bash tools/quickstart.sh test     # set up, build with -Werror, run all tests, then again
#                                     # under AddressSanitizer + UndefinedBehaviorSanitizer,
#                                     # then each fuzz harness for 60 s (tools/fuzz.sh)
#
# The last line of `test` is "N passed, N failed" (counted over the three builds).
set -euo pipefail
cd "$(dirname "$0")/.."
mode="${1:-run}"

# --- 1. Debian packages (only those missing; apt runs only if something is) ---------------------
# libopenblas-dev: CHOLMOD is ~8x faster on OpenBLAS than on the reference BLAS (DESIGN.md);
# the build links it explicitly (meson.build), so the choice does not rest on
# update-alternatives. Rendering: EGL and libOpenGL (glvnd) with Mesa's llvmpipe for machines
# without a GPU, FreeType and the DejaVu font for the frames' text, ffmpeg for the videos.
# `needlesim live`: civetweb (HTTP + WebSocket), libjpeg-turbo (the frames). Its tests only: the
# scripted client uses python3-websockets with Debian's /usr/bin/python3, the browser test
# Chromium (headless, driven over the DevTools protocol by Python's standard library).
packages=(gcc pkg-config meson ninja-build liblua5.4-dev libsuitesparse-dev libmetis-dev
          libopenblas-dev libpng-dev libegl-dev libopengl-dev libgl-dev libegl-mesa0
          libgl1-mesa-dri libfreetype-dev fonts-dejavu-core ffmpeg python3
          libcivetweb-dev libjpeg62-turbo-dev)
if [ "$mode" = test ]; then
    packages+=(python3-websockets chromium)
fi
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "installing: ${missing[*]}" >&2
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
fi

# --- 2. Build ------------------------------------------------------------------------------------
# One thread for OpenBLAS unless the caller says otherwise: on a 2-core machine more slowed the
# factorization (DESIGN.md). The program sets this itself too; CHOLMOD 3's own OpenMP loops
# ignore OMP_NUM_THREADS (their count is fixed at compile time), so sim/solver.c switches them
# off around each factorization. Our own parallel loops take an explicit thread count.
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"

build() { # dir, extra meson options...
    local dir="$1"; shift
    if [ ! -f "$dir/build.ninja" ]; then
        meson setup "$dir" "$@" >&2
    else
        meson configure "$dir" "$@" >&2
    fi
    ninja -C "$dir" >&2
}

case "$mode" in
run)
    build build -Dbuildtype=release
    out="${NEEDLESIM_OUT:-out/brachytherapy}"
    mkdir -p "$out"
    ./build/needlesim check scenarios/brachytherapy.lua --mesh-out "$out/tissue.vtu"
    echo "mesh written to $out/tissue.vtu" >&2
    # The run: two needles, four seeds; the report, the trajectory, the debrief video and its
    # contact sheet (summary.png).
    ./build/needlesim run scenarios/brachytherapy.lua -o "$out" --video "$out/brachytherapy.mp4"
    ;;
test)
    passed=0; failed=0
    # A build that breaks still ends with the summary line CI reads.
    trap 'rc=$?; [ $rc -eq 0 ] || echo "$passed passed, $((failed + 1)) failed"' EXIT
    count() { # dir: add the meson test summary of dir to the totals
        local ok fail
        ok=$(sed -n 's/^ *Ok: *\([0-9]*\).*/\1/p' "$1/summary.txt" 2>/dev/null | tail -1)
        fail=$(sed -n 's/^ *\(Fail\|Timeout\|Unexpected Pass\): *\([0-9]*\).*/\2/p' "$1/summary.txt" 2>/dev/null | awk '{s+=$1} END {print s+0}')
        passed=$((passed + ${ok:-0})); failed=$((failed + ${fail:-0}))
    }
    runtests() { # dir
        set +e
        # meson runs two tests at once on the 2 cores, so a test's second OpenMP thread competes
        # with the other test: threads that wait asleep, not spinning, leave it the core (a
        # 2-thread tutorial run beside a busy process: 5.8 s against 11.2 s). Results do not
        # depend on it (docs/solvers.md, "Threads and determinism").
        OMP_WAIT_POLICY=passive meson test -C "$1" --print-errorlogs 2>&1 | tee "$1/summary.txt"
        set -e
        count "$1"
    }
    build build -Dbuildtype=debugoptimized -Dwerror=true
    runtests build
    # The sanitizer build is optimized (-O2 -g): at -O0 its tests took ~28 of CI's minutes on a
    # slow day, past the 30-minute budget; at -O2 13 minutes, the same tests, the same checks.
    build build-asan -Dbuildtype=debugoptimized -Dwerror=true -Db_sanitize=address,undefined \
        -Db_lundef=false
    UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 ASAN_OPTIONS=detect_leaks=1 runtests build-asan
    # The fuzz build (clang, libFuzzer; it installs clang if missing): its only tests are the
    # three harnesses' 60-second regression runs on their seed corpora, two at a time
    # (docs/reliability.md, "Fuzzing"). The unit and command-line tests are not built there.
    bash tools/fuzz.sh build
    runtests build-fuzz
    trap - EXIT
    echo "$passed passed, $failed failed"
    [ "$failed" -eq 0 ]
    ;;
*)
    echo "usage: bash tools/quickstart.sh [run|test]" >&2
    exit 2
    ;;
esac
