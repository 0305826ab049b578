#!/usr/bin/env python3
"""Mutation check of the validation suite (issue 35, docs/validation.md "Mutations").

Every physical constant must be caught by some `needlesim validate` case when it is wrong by 20%.
A mutation build (meson -Dmutation=true, sim/mutate.h) scales the constant where it enters the
physics by the factor the environment variable NS_MUTATE gives. This script builds one (in
build-mutate/ unless --bin names one), runs the cases unmutated (all must pass), then once per
constant and factor, and prints a markdown table: which cases each mutation fails, with their
error against their tolerance. It exits 1 if a mutation fails no case, or a case fails unmutated.

    python3 tools/mutate.py [--bin PATH] [--cases CASE ...] [--factors 0.8 1.2]
                            [--constants NAME ...] [--first]

--first stops a mutation at its first failing case (cases run in the order given, each
constant's likely catchers first). A benchmark-sized job, not a test: the whole suite once per
mutation (about 11 runs of `needlesim validate`).
"""
import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONSTANTS = ["bevel_force", "bevel_arc", "bevel_disp", "gj", "ei", "youngs", "friction"]
# The cases each constant should fail first (tried first with --first); the rest follow.
LIKELY = {
    "bevel_force": ["bevel-arc", "double-bend"],
    "bevel_arc": ["bevel-arc", "double-bend"],
    "bevel_disp": ["bevel-displacement", "bevel-arc"],
    "gj": ["rod-torsion", "twist-friction", "rod-twist"],
    "ei": ["rod-cantilever", "rod-buckling"],
    "youngs": ["fem-compression", "fem-cantilever", "fem-vibration"],
    "friction": ["friction-slip", "puncture", "twist-friction"],
}


def build(bindir):
    if not os.path.exists(os.path.join(bindir, "build.ninja")):
        subprocess.run(["meson", "setup", bindir, "-Dmutation=true", "-Dtests=false",
                        "-Dbuildtype=debugoptimized"], cwd=ROOT, check=True,
                       stdout=sys.stderr)
    subprocess.run(["ninja", "-C", bindir], cwd=ROOT, check=True, stdout=sys.stderr)
    return os.path.join(bindir, "needlesim")


def list_cases(binary):
    out = subprocess.run([binary, "validate", "--list"], capture_output=True, text=True,
                         check=True).stdout
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def run_case(binary, case, mutation):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env.pop("NS_MUTATE", None)
    if mutation:
        env["NS_MUTATE"] = mutation
    t0 = time.monotonic()
    p = subprocess.run([binary, "validate", "--json", case], capture_output=True, text=True,
                       env=env)
    secs = time.monotonic() - t0
    try:
        r = json.loads(p.stdout)["cases"][0]
    except (ValueError, KeyError, IndexError):
        return {"name": case, "pass": False, "error": float("nan"), "tolerance": float("nan"),
                "detail": "no result (exit %d): %s" % (p.returncode, p.stderr.strip()[-200:]),
                "seconds": secs}
    r["seconds"] = secs
    return r


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", help="a needlesim built with -Dmutation=true")
    ap.add_argument("--cases", nargs="*", help="cases to run (default: all)")
    ap.add_argument("--factors", nargs="*", type=float, default=[0.8, 1.2])
    ap.add_argument("--constants", nargs="*", default=CONSTANTS)
    ap.add_argument("--first", action="store_true", help="stop a mutation at its first failure")
    a = ap.parse_args()
    binary = a.bin or build(os.path.join(ROOT, "build-mutate"))
    cases = a.cases or list_cases(binary)

    broken = []
    for case in cases:
        r = run_case(binary, case, None)
        print("unmutated %-20s %s (%.0f s)" % (case, "pass" if r["pass"] else "FAIL",
                                               r["seconds"]), file=sys.stderr)
        if not r["pass"]:
            broken.append(case)
    if broken:
        print("cases failing unmutated: %s" % " ".join(broken), file=sys.stderr)
        return 1

    rows, uncaught = [], []
    for const in a.constants:
        order = [c for c in LIKELY.get(const, []) if c in cases]
        order += [c for c in cases if c not in order]
        for f in a.factors:
            mutation = "%s=%g" % (const, f)
            failed = []
            ran = 0
            for case in order:
                r = run_case(binary, case, mutation)
                ran += 1
                print("%-14s %-20s %s (%.0f s)" % (mutation, case,
                                                   "pass" if r["pass"] else "FAIL",
                                                   r["seconds"]), file=sys.stderr)
                if not r["pass"]:
                    failed.append("%s (%.3g / %.3g)" % (case, r["error"], r["tolerance"]))
                    if a.first:
                        break
            rows.append((mutation, failed, ran))
            if not failed:
                uncaught.append(mutation)

    print("| mutation | cases failed (error / tolerance) | cases run |")
    print("|---|---|---|")
    for mutation, failed, ran in rows:
        print("| `NS_MUTATE=%s` | %s | %d |" % (mutation, ", ".join(failed) or "**none**", ran))
    if uncaught:
        print("mutations no case catches: %s" % " ".join(uncaught), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
