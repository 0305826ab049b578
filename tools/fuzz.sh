#!/usr/bin/env bash
# needlesim's fuzzing: libFuzzer harnesses for the three parsers of untrusted input (fuzz/,
# docs/reliability.md "Fuzzing").
#
#   bash tools/fuzz.sh build                 # clang + libFuzzer if missing, then build-fuzz/
#   bash tools/fuzz.sh run TARGET SECONDS    # one harness for SECONDS (TARGET: mesh, log, scenario)
#   bash tools/fuzz.sh campaign [TARGET...]  # each harness to 1,000,000 executions, one at a time
#
# Every run works on a copy of the seed corpus fuzz/corpus/TARGET in a scratch folder under
# ${TMPDIR:-/tmp}, so the repository is never written to. A finding (crash, sanitizer report,
# leak, an input slower than 10 s, more than 2 GB of memory) makes the run exit 1; its input
# and log stay in the scratch folder, whose path is printed. `run` takes an optional third
# argument, the harness program (meson's fuzz tests pass their own build's).
#
# Environment: FUZZ_BUILD (build folder, default build-fuzz), FUZZ_RUNS (campaign executions per
# target, default 1000000), FUZZ_JOBS (ninja jobs, default 2).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
mode="${1:-}"
build_dir="${FUZZ_BUILD:-$root/build-fuzz}"
targets_all=(mesh log scenario)

# libFuzzer's limits, the same for every run: an input is a finding if it takes longer than
# this [s] or the process grows past this [MB] (one allocation past it too: malloc_limit_mb
# defaults to rss_limit_mb).
timeout_s=10
rss_mb=2048

usage() {
    echo "usage: bash tools/fuzz.sh build | run TARGET SECONDS [HARNESS] | campaign [TARGET...]" >&2
    echo "       TARGET: ${targets_all[*]}" >&2
    exit 2
}

check_target() {
    case "$1" in
    mesh | log | scenario) ;;
    *) usage ;;
    esac
}

# The harnesses' environment: `require "needlesim"` finds this tree's scripts; undefined
# behaviour stops with a stack (the build also makes it non-recoverable).
export NEEDLESIM_SCRIPTS="$root/scripts"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"

# One libFuzzer run of TARGET on a scratch copy of its corpus. Args: target, harness, then
# libFuzzer flags (the duration). Sets $scratch and $finding (0 or 1); the log is $scratch/log.
fuzz_once() {
    local target="$1" harness="$2"
    shift 2
    [ -x "$harness" ] || { echo "fuzz.sh: no harness $harness (run: bash tools/fuzz.sh build)" >&2; exit 1; }
    scratch="$(mktemp -d "${TMPDIR:-/tmp}/needlesim-fuzz-$target.XXXXXX")"
    mkdir -p "$scratch/corpus" "$scratch/findings"
    cp "$root/fuzz/corpus/$target/"* "$scratch/corpus/"
    local rc=0
    # TMPDIR: the harness's own input files go to a folder of the scratch one.
    mkdir -p "$scratch/tmp"
    TMPDIR="$scratch/tmp" "$harness" "$scratch/corpus" -dict="$root/fuzz/$target.dict" \
        -timeout="$timeout_s" -rss_limit_mb="$rss_mb" -print_final_stats=1 \
        -artifact_prefix="$scratch/findings/" "$@" >"$scratch/log" 2>&1 || rc=$?
    finding=0
    if [ "$rc" -ne 0 ] || [ -n "$(ls -A "$scratch/findings")" ]; then
        finding=1
    fi
}

# The figures of $scratch/log: executions, cov, ft, corpus size, peak RSS (libFuzzer's final
# stats and its last status line).
stats() {
    local log="$scratch/log"
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$log" | tail -1)
    local last
    last=$(grep -a -E '^#[0-9]+' "$log" | tail -1 || true)
    cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
    ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
    corp=$(sed -n 's/.* corp: \([0-9]*\/[0-9A-Za-z]*\).*/\1/p' <<<"$last")
}

report_finding() {
    echo "FINDING in $1: input and log kept in $scratch" >&2
    ls -l "$scratch/findings" >&2 || true
    grep -E -m1 -A12 'ERROR: |runtime error|==[0-9]+==' "$scratch/log" >&2 || tail -30 "$scratch/log" >&2
}

case "$mode" in
build)
    # clang and its runtime libraries (libFuzzer, the sanitizers): Debian 12's clang-14.
    missing=()
    for p in clang libclang-rt-14-dev; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    if [ ${#missing[@]} -gt 0 ]; then
        echo "installing: ${missing[*]}" >&2
        sudo=""
        [ "$(id -u)" -eq 0 ] || sudo="sudo"
        $sudo apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
    fi
    # OpenMP off: clang would need libomp, and the parsers run no parallel loops.
    opts=(-Dfuzz=true -Dbuildtype=debugoptimized -Dwerror=true -Db_sanitize=address,undefined
          -Db_lundef=false -Dopenmp=disabled)
    if [ ! -f "$build_dir/build.ninja" ]; then
        CC=clang meson setup "$build_dir" "${opts[@]}" >&2
    else
        meson configure "$build_dir" "${opts[@]}" >&2
    fi
    ninja -C "$build_dir" -j"${FUZZ_JOBS:-2}" >&2
    ;;
run)
    [ $# -ge 3 ] || usage
    target="$2"
    seconds="$3"
    check_target "$target"
    harness="${4:-$build_dir/fuzz/fuzz_$target}"
    fuzz_once "$target" "$harness" -max_total_time="$seconds"
    stats
    echo "fuzz $target: ${execs:-?} executions in ${seconds} s, cov ${cov:-?}, ft ${ft:-?}, corpus ${corp:-?}, peak RSS ${rss:-?} MB"
    if [ "$finding" -ne 0 ]; then
        report_finding "$target"
        exit 1
    fi
    rm -rf "$scratch"
    ;;
campaign)
    shift
    targets=("$@")
    [ ${#targets[@]} -gt 0 ] || targets=("${targets_all[@]}")
    runs="${FUZZ_RUNS:-1000000}"
    commit=$(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo "?")
    day=$(date -u +%Y-%m-%d)
    failed=0
    rows=()
    # One target at a time: libFuzzer uses one core, and the machine is shared.
    for target in "${targets[@]}"; do
        check_target "$target"
        echo "fuzz $target: $runs executions ..." >&2
        t0=$(date +%s)
        fuzz_once "$target" "$build_dir/fuzz/fuzz_$target" -runs="$runs"
        secs=$(($(date +%s) - t0))
        stats
        crashes=$(find "$scratch/findings" -type f | wc -l)
        rows+=("| $target | ${execs:-?} | $crashes | ${cov:-?} | ${ft:-?} | $secs | $day | $commit |")
        if [ "$finding" -ne 0 ]; then
            report_finding "$target"
            failed=1
        else
            rm -rf "$scratch"
        fi
    done
    echo "| target | executions | crashes | cov | ft | seconds | date | commit |"
    echo "| --- | ---: | ---: | ---: | ---: | ---: | --- | --- |"
    printf '%s\n' "${rows[@]}"
    exit "$failed"
    ;;
*)
    usage
    ;;
esac
