#!/usr/bin/env python3
"""Convergence of the tip path under refinement (issue 35, docs/needle.md, "Convergence").

Runs a scenario (default: the phantom single bend) at successive refinement levels
(tissue.refine r: element size h = 13 mm / r on the phantom; --halve-dt refines dt with h), and
prints per level the RMS distance d_k between its tip path and the previous level's, the paths
matched at equal insertion depth (resampled every 0.5 mm over the depth all reach), and the
observed order p solving d_(k-1) / d_k = (h_(k-2)^p - h_(k-1)^p) / (h_(k-1)^p - h_k^p) (for
halvings, p = log2(d_(k-1) / d_k)). With three or more levels it also gives the
Richardson-extrapolated path's distance from the finest (p the last observed order, clamped to
[0.5, 4]). --dt-levels instead refines dt alone at one mesh (tissue.refine = --levels' first).

    python3 tools/converge.py [--bin build/needlesim] [--scenario FILE] [--levels 1,2,4]
                              [--dt 0.01] [--halve-dt] [--set KEY=VALUE]... [--jobs N]
                              [--keep DIR] [--csv FILE]

--halve-dt halves dt at each level along with h; --levels lists the tissue.refine values.
With --keep, each level's trajectory.csv is kept in DIR (and reused when present). Runs are
independent: --jobs runs that many at once.
"""
import argparse
import bisect
import concurrent.futures
import csv
import math
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def tip_path(path):
    """(depths, points): the tip's rows where its depth first grows, in insertion order."""
    rows = list(csv.reader(open(path)))
    head = rows[0]
    ix, iy, iz, idp = (head.index(c) for c in ("tip_x_m", "tip_y_m", "tip_z_m", "depth_m"))
    keys, pts, best = [], [], -math.inf
    for r in rows[1:]:
        d = float(r[idp])
        if d > best:
            best = d
            keys.append(d)
            pts.append((float(r[ix]), float(r[iy]), float(r[iz])))
    return keys, pts


def at(keys, pts, k):
    i = bisect.bisect_left(keys, k)
    if i <= 0:
        return pts[0]
    if i >= len(keys):
        return pts[-1]
    a = (k - keys[i - 1]) / (keys[i] - keys[i - 1])
    return tuple(p + a * (q - p) for p, q in zip(pts[i - 1], pts[i]))


def grid(paths, step=5e-4):
    lo = max(k[0] for k, _ in paths)
    hi = min(k[-1] for k, _ in paths)
    n = int((hi - lo) / step)
    return [lo + i * step for i in range(n + 1)]


def rms(a, b):
    return math.sqrt(sum(math.dist(p, q) ** 2 for p, q in zip(a, b)) / len(a))


def order(h, d1, d2):
    """p with d1 / d2 = (h0^p - h1^p) / (h1^p - h2^p), h = (h0, h1, h2) decreasing; None if
    the differences do not shrink."""
    if not (d1 > d2 > 0):
        return None
    f = lambda p: (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - d1 / d2
    lo, hi = 1e-3, 20.0
    if f(lo) > 0 or f(hi) < 0:
        return None
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


def run_level(a, refine, dt):
    name = "refine%g_dt%g" % (refine, dt)
    out = os.path.join(a.keep, name)
    traj = os.path.join(out, "trajectory.csv")
    if os.path.exists(traj):
        return traj, None
    cmd = [a.bin, "run", a.scenario, "--no-render", "--quiet", "-o", out,
           "--set", "tissue.refine=%g" % refine, "--set", "dt=%r" % dt]
    for s in a.set:
        cmd += ["--set", s]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        last = p.stderr.strip().splitlines()
        return None, last[-1] if last else "exit %d" % p.returncode
    return traj, None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "needlesim"))
    ap.add_argument("--scenario", default=os.path.join(ROOT, "scenarios",
                                                       "phantom_single_bend.lua"))
    ap.add_argument("--levels", default="1,2,4")
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--halve-dt", action="store_true")
    ap.add_argument("--dt-levels", default=None, help="e.g. 0.01,0.005,0.0025")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--keep", default="/tmp/needlesim-converge")
    ap.add_argument("--csv", default=None)
    a = ap.parse_args()
    os.makedirs(a.keep, exist_ok=True)
    levels = [float(x) for x in a.levels.split(",")]
    dts = [a.dt * (levels[0] / r if a.halve_dt else 1.0) for r in levels]
    if a.dt_levels:
        dts = [float(x) for x in a.dt_levels.split(",")]
        levels = [levels[0]] * len(dts)
    # the refined quantity: h, or dt alone
    hs = [d for d in dts] if a.dt_levels else [13.0 / r for r in levels]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    os.environ.update(env)
    with concurrent.futures.ThreadPoolExecutor(a.jobs) as ex:
        res = list(ex.map(lambda rd: run_level(a, *rd), zip(levels, dts)))
    for (r, dt), (traj, err) in zip(zip(levels, dts), res):
        if err:
            sys.exit("refine %g dt %g failed: %s" % (r, dt, err))
    paths = [tip_path(t) for t, _ in res]
    ks = grid(paths)
    sampled = [[at(k, p, d) for d in ks] for k, p in paths]
    print("tip path over depth %.1f-%.1f mm, %d samples" % (1e3 * ks[0], 1e3 * ks[-1], len(ks)))
    print("| refine | h [mm] | dt [s] | final tip y [mm] | RMS to previous [mm] | max [mm] | p |")
    print("|---|---|---|---|---|---|---|")
    rows, prev = [], None
    for i, (r, dt) in enumerate(zip(levels, dts)):
        fin = 1e3 * sampled[i][-1][1]
        d = rms(sampled[i], sampled[i - 1]) if i else None
        mx = max(math.dist(p, q) for p, q in zip(sampled[i], sampled[i - 1])) if i else None
        p = order(hs[i - 2:i + 1], prev, d) if prev and d else None
        print("| %g | %.2f | %g | %.2f | %s | %s | %s |" % (
            r, 13.0 / r, dt, fin, "%.3f" % (1e3 * d) if d is not None else "-",
            "%.3f" % (1e3 * mx) if mx is not None else "-", "%.2f" % p if p else "-"))
        rows.append({"refine": r, "dt": dt, "final_tip_y_mm": fin,
                     "rms_to_previous_mm": 1e3 * d if d is not None else "",
                     "order": p if p else ""})
        prev = d
    if len(levels) >= 3:
        # Richardson: the finest path plus (f_n - f_(n-1)) / (r^p - 1), r the refinement ratio
        ratio = hs[-2] / hs[-1]
        d1, d2 = rms(sampled[-2], sampled[-3]), rms(sampled[-1], sampled[-2])
        p = order(hs[-3:], d1, d2)
        p = min(4.0, max(0.5, p)) if p else 1.0
        ext = [tuple(f + (f - g) / (ratio ** p - 1) for f, g in zip(pf, pg))
               for pf, pg in zip(sampled[-1], sampled[-2])]
        print("Richardson (p = %.2f): RMS distance of the extrapolated path from the finest "
              "%.3f mm" % (p, 1e3 * rms(ext, sampled[-1])))
    if a.csv:
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


if __name__ == "__main__":
    main()
