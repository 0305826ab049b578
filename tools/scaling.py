#!/usr/bin/env python3
"""Step time against mesh size (issue 9, docs/performance.md).

Benchmarks the phantom (single bend) scenario on meshes from ~3k to ~150k tets
(`--set tissue.refine=k`: the same block, the same needle, resolution 13 mm / k) with
`needlesim bench --json`, and fits the growth exponent p of median step time ~ tets^p by least
squares on the logarithms.

    python3 tools/scaling.py [--bin build/needlesim] [--steps 60] [--solver schur]

A benchmark, not a test.
"""
import argparse
import json
import math
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REFINES = [1, 2, 3, 4]  # whole cells in every direction: the entry stays on the lattice


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "needlesim"))
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--solver", default="schur")
    a = ap.parse_args()
    pts = []
    print("| refine | tets | nodes | median step ms | p95 ms | tissue ms | LCP ms |")
    print("|---|---|---|---|---|---|---|")
    for k in REFINES:
        cmd = [a.bin, "bench", os.path.join(ROOT, "scenarios", "phantom_single_bend.lua"),
               "--steps", str(a.steps), "--solver", a.solver, "--json",
               "--set", "tissue.refine=%r" % k]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            sys.exit("refine %g: %s" % (k, p.stderr.strip()))
        r = json.loads(p.stdout)
        pts.append((r["tets"], r["step_ms"]["median"]))
        print("| %g | %d | %d | %.2f | %.2f | %.2f | %.2f |" % (
            k, r["tets"], r["nodes"], r["step_ms"]["median"], r["step_ms"]["p95"],
            r["stages_ms"]["tissue"], r["stages_ms"]["lcp"]), flush=True)
    xs = [math.log(t) for t, _ in pts]
    ys = [math.log(m) for _, m in pts]
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    p = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    print("\ngrowth exponent (median step time ~ tets^p, %d to %d tets, solver %s): p = %.2f"
          % (pts[0][0], pts[-1][0], a.solver, p))


if __name__ == "__main__":
    main()
