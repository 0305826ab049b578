#!/usr/bin/env python3
"""Speed against accuracy (issue 9, docs/performance.md).

Runs the phantom (single bend) and brachytherapy scenarios over mesh resolution, time step,
solver tolerance and lazy-Jacobian threshold with `needlesim run`, measures each run's median
step time and its error against a reference of the same scenario: on the phantom, the
Richardson-extrapolated tip path of a ladder of mesh refinements (tissue.refine 1, 2, 4 at the
smallest dt, tightest tolerance, Jacobians rebuilt every step; the ladder's successive RMS
differences and observed order are printed and written to docs/speed-accuracy-reference.csv),
the markers against the ladder's finest run; on brachytherapy (whose template holes need the
scenario's own mesh) the seeds against its tightest run (smallest dt and tolerance), not
extrapolated. Each error is matched at equal tip depth (and the final tips). It writes
docs/speed-accuracy.csv and, with gnuplot, docs/speed-accuracy.png: one panel per scenario and
error metric, each point labelled with the setting it changes, the Pareto front drawn, the
default settings circled, the reference named in the panel's title.

    python3 tools/speed_accuracy.py [--bin build/needlesim] [--out docs] [--only phantom]
    python3 tools/speed_accuracy.py --chart-only   # redraw the chart from the CSV

A benchmark, not a test: it takes about half an hour on the 2-core machine. Times are medians of
each run's own steps; the machine is shared, so compare within one sweep only.
"""
import argparse
import bisect
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The engine's defaults (sim/coupling.c, sim/tissue.c) and the scenarios' dt.
DEFAULT = {"tissue.refine": 1, "dt": 0.01, "solver.tolerance": 1e-8,
           "solver.lazy_threshold": 1e-2}

SCENARIOS = {
    "phantom": {
        "file": "scenarios/phantom_single_bend.lua",
        "reference": {"dt": 0.005, "solver.tolerance": 1e-10, "solver.lazy_threshold": 0.0},
        # Richardson extrapolation over these tissue.refine levels (each halving h)
        "ladder": [1, 2, 4],
        # one parameter at a time from the defaults, and a few cheap combinations
        "runs": [
            {},
            {"tissue.refine": 2},
            {"dt": 0.02}, {"dt": 0.005},
            {"solver.tolerance": 1e-4}, {"solver.tolerance": 1e-6}, {"solver.tolerance": 1e-10},
            {"solver.lazy_threshold": 0.0}, {"solver.lazy_threshold": 0.05},
            {"solver.lazy_threshold": 0.2},
            {"dt": 0.02, "solver.tolerance": 1e-4, "solver.lazy_threshold": 0.05},
            {"dt": 0.02, "solver.tolerance": 1e-6},
            {"tissue.refine": 2, "dt": 0.005},
            {"tissue.refine": 2, "dt": 0.02, "solver.tolerance": 1e-6},
        ],
    },
    "brachytherapy": {
        "file": "scenarios/brachytherapy.lua",
        # Two needles and four seeds: the script's actions end on step boundaries, so runs with
        # another dt drift apart in time and a time-matched tip says little. The tip is compared
        # where it matters and where the runs can be matched: the seeds, where each lies at the
        # end of the run.
        "metric": "seeds",
        # the template holes need the scenario's own mesh: resolution is not swept here
        "reference": {"dt": 0.005, "solver.tolerance": 1e-10, "solver.lazy_threshold": 0.0},
        "runs": [
            {},
            {"dt": 0.02}, {"dt": 0.005},
            {"solver.tolerance": 1e-4}, {"solver.tolerance": 1e-6},
            {"solver.lazy_threshold": 0.0}, {"solver.lazy_threshold": 0.05},
            {"dt": 0.02, "solver.tolerance": 1e-6, "solver.lazy_threshold": 0.05},
            # a live session's step: twice the dt, the same cost a step (docs/live.md)
            {"dt": 0.04}, {"dt": 0.04, "solver.tolerance": 1e-6, "solver.lazy_threshold": 0.05},
        ],
    },
}


def label(sets):
    if not sets:
        return "default"
    short = {"tissue.refine": "refine", "dt": "dt", "solver.tolerance": "tol",
             "solver.lazy_threshold": "lazy"}
    return " ".join("%s=%g" % (short[k], v) for k, v in sorted(sets.items()))


def run(binary, scenario, sets, tmp):
    out = tempfile.mkdtemp(dir=tmp)
    cmd = [binary, "run", os.path.join(ROOT, scenario), "--no-render", "--quiet", "-o", out]
    for k, v in sorted(sets.items()):
        cmd += ["--set", "%s=%r" % (k, v)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        return None, p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "exit %d" % p.returncode
    rep = json.load(open(os.path.join(out, "report.json")))
    rows = list(csv.reader(open(os.path.join(out, "trajectory.csv"))))
    head, body = rows[0], [[float(x) for x in r] for r in rows[1:]]
    shutil.rmtree(out)
    return {"report": rep, "head": head, "rows": body}, None


def points(traj, prefix_cols):
    """The time column and the 3D points of each named column triple."""
    head = traj["head"]
    t = [r[0] for r in traj["rows"]]
    out = {}
    for name, cols in prefix_cols.items():
        idx = [head.index(c) for c in cols]
        out[name] = [(r[idx[0]], r[idx[1]], r[idx[2]]) for r in traj["rows"]]
    return t, out


def triples(head):
    """tip and every marker: name -> (x, y, z) column names."""
    res = {"tip": ("tip_x_m", "tip_y_m", "tip_z_m")}
    for c in head[12:]:  # after the fixed columns (docs/scenarios.md): the markers
        if c.endswith("_x_m"):
            base = c[:-4]
            res[base] = (base + "_x_m", base + "_y_m", base + "_z_m")
    return res


def interp(ts, ps, t):
    i = bisect.bisect_left(ts, t)
    if i <= 0:
        return ps[0]
    if i >= len(ts):
        return ps[-1]
    a = (t - ts[i - 1]) / (ts[i] - ts[i - 1])
    return tuple(p0 + a * (p1 - p0) for p0, p1 in zip(ps[i - 1], ps[i]))


def progress(traj):
    """The key the runs are matched by: the tip's depth (depth_m), kept non-decreasing. The
    insertion stops when the tip reaches its depth, so runs on other meshes or steps take
    different times to get there; matching at equal times would compare a tip still going in
    with one already waiting (~1.9 s apart at 10 mm/s on the phantom: 19 mm)."""
    col = traj["head"].index("depth_m")
    keys, best = [], -math.inf
    for r in traj["rows"]:
        best = max(best, r[col])
        keys.append(best)
    return keys


def errors(run_traj, ref_traj):
    """Largest tip distance and largest marker distance from the reference over the insertion,
    matched at equal tip depth, and the distance between the final tips [m]."""
    cols = triples(ref_traj["head"])
    _, pr = points(ref_traj, cols)
    _, pt = points(run_traj, cols)
    kr, kt = progress(ref_traj), progress(run_traj)
    # the reference's rows where its depth first grows (one row per depth)
    idx = [i for i in range(len(kr)) if i == 0 or kr[i] > kr[i - 1]]
    keys = [kr[i] for i in idx]
    tip, marker = 0.0, 0.0
    for name in cols:
        ref_pts = [pr[name][i] for i in idx]
        worst = 0.0
        for k, p in zip(kt, pt[name]):
            if k > keys[-1]:
                k = keys[-1]
            worst = max(worst, math.dist(p, interp(keys, ref_pts, k)))
        if name == "tip":
            tip = worst
        else:
            marker = max(marker, worst)
    final = math.dist(pt["tip"][-1], pr["tip"][-1])
    return max(tip, final), marker


def richardson(trajs, levels, out_dir):
    """The Richardson-extrapolated tip path of runs at successive halvings of the element size
    (trajs, coarsest first), as a trajectory dict with the finest run's rows (its markers) and
    its tip replaced by f_n + (f_n - f_(n-1)) / (2^p - 1) at equal depth, p the observed order
    log2(d_(n-1) / d_n) of the RMS successive differences (clamped to [0.5, 4]). Prints the
    differences and writes them to speed-accuracy-reference.csv."""
    cols = triples(trajs[0]["head"])
    paths = []
    for tr in trajs:
        _, pt = points(tr, cols)
        k = progress(tr)
        idx = [i for i in range(len(k)) if i == 0 or k[i] > k[i - 1]]
        paths.append(([k[i] for i in idx], [pt["tip"][i] for i in idx]))
    lo, hi = max(p[0][0] for p in paths), min(p[0][-1] for p in paths)
    grid = [lo + (hi - lo) * i / 400 for i in range(401)]
    samp = [[interp(k, p, g) for g in grid] for k, p in paths]

    def rms(a, b):
        return math.sqrt(sum(math.dist(x, y) ** 2 for x, y in zip(a, b)) / len(a))

    diffs = [rms(samp[i], samp[i - 1]) for i in range(1, len(samp))]
    p = math.log2(diffs[-2] / diffs[-1]) if len(diffs) >= 2 and diffs[-1] > 0 else 1.0
    p = min(4.0, max(0.5, p))
    ext = [tuple(f + (f - g) / (2 ** p - 1) for f, g in zip(pf, pg))
           for pf, pg in zip(samp[-1], samp[-2])]
    rows = [{"refine": levels[0], "rms_to_previous_mm": "", "order": ""}]
    for i, d in enumerate(diffs):
        o = math.log2(diffs[i - 1] / d) if i and d > 0 else ""
        rows.append({"refine": levels[i + 1], "rms_to_previous_mm": 1e3 * d, "order": o})
    rows.append({"refine": "extrapolated", "rms_to_previous_mm": 1e3 * rms(ext, samp[-1]),
                 "order": p})
    for r in rows:
        print("  reference ladder: refine %s  RMS to previous %s mm  order %s" % (
            r["refine"], r["rms_to_previous_mm"], r["order"]), flush=True)
    with open(os.path.join(out_dir, "speed-accuracy-reference.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    # the finest run, its tip path replaced by the extrapolated one, resampled on the grid
    fin = trajs[-1]
    head = fin["head"]
    ix, idp = head.index("tip_x_m"), head.index("depth_m")
    base = [r for r in fin["rows"]]
    rows_out = []
    for g, q in zip(grid, ext):
        j = min(range(len(base)), key=lambda i: abs(base[i][idp] - g))
        r = list(base[j])
        r[ix:ix + 3] = q
        r[idp] = g
        rows_out.append(r)
    return {"report": None, "head": head, "rows": rows_out}


def seed_errors(rep, ref):
    """Largest distance between a run's seeds and the reference's, seed by seed, where they lie
    at the end of the run (report seeds[].position_m) [m]; None if the counts differ."""
    a, b = rep["seeds"], ref["seeds"]
    if len(a) != len(b):
        return None
    return max((math.dist(x["position_m"], y["position_m"]) for x, y in zip(a, b)),
               default=0.0)


def pareto(rows):
    """Marks the rows no other row beats in both cost and tip error (errors within 1 um of
    each other count as equal: the runs differ below what the reference resolves)."""
    def err(r):
        return round(r["tip_error_mm"], 3)
    for r in rows:
        r["pareto"] = not any(o is not r and o["cost_ms_per_s"] <= r["cost_ms_per_s"]
                              and err(o) <= err(r)
                              and (o["cost_ms_per_s"] < r["cost_ms_per_s"] or err(o) < err(r))
                              for o in rows)


def write_fronts(rows):
    """scripts/needlesim/fronts.lua: each scenario's Pareto front, cheapest first, for
    ns.economy and a scenario's `accuracy` field."""
    path = os.path.join(ROOT, "scripts", "needlesim", "fronts.lua")
    with open(path, "w") as f:
        f.write("-- Measured speed-against-accuracy fronts: written by tools/speed_accuracy.py "
                "(do not edit;\n-- docs/performance.md). Per scenario, the Pareto-optimal "
                "settings, cheapest first: tip_error\n-- is the largest tip distance from the "
                "converged reference run [m], cost the median step\n-- time per simulated "
                "second [ms/s] on the project's 2-core machine.\nreturn {\n")
        for sc in sorted({r["scenario"] for r in rows}):
            front = sorted((r for r in rows if r["scenario"] == sc and r["pareto"] in
                            (True, "True")), key=lambda r: r["cost_ms_per_s"])
            f.write("    %s = {\n" % sc)
            for r in front:
                f.write("        { label = %s, dt = %r, refine = %r, tolerance = %r, "
                        "lazy_threshold = %r,\n          tip_error = %.6g, cost = %.6g },\n" % (
                            json.dumps(r["label"]), float(r["dt"]), float(r["refine"]),
                            float(r["tolerance"]), float(r["lazy_threshold"]),
                            1e-3 * float(r["tip_error_mm"]), float(r["cost_ms_per_s"])))
            f.write("    },\n")
        f.write("}\n")
    print("wrote %s" % path)


PANELS = [  # (scenario, column, what the error is)
    ("phantom", "tip_error_mm", "phantom: largest tip distance over the path [mm]"),
    ("phantom", "marker_error_mm", "phantom: largest marker distance [mm]"),
    ("brachytherapy", "tip_error_mm", "brachytherapy: largest seed distance [mm]"),
]


def chart(rows, out_dir):
    """One panel per scenario and error metric (PANELS), each point labelled with the setting it
    changes from the defaults, its Pareto front drawn, the default circled, the reference in the
    panel's title."""
    if not shutil.which("gnuplot"):
        print("gnuplot not found (apt install gnuplot-nox): no chart", file=sys.stderr)
        return
    work = tempfile.mkdtemp(prefix="needlesim-chart.")  # gnuplot's input, removed after
    panels = [p for p in PANELS if any(r["scenario"] == p[0] for r in rows)]
    gp = os.path.join(work, "speed-accuracy.gp")
    with open(gp, "w") as f:
        f.write("set terminal pngcairo size 1400,%d font 'DejaVu Sans,10'\n" % (430 * len(panels)))
        f.write("set output '%s'\n" % os.path.join(out_dir, "speed-accuracy.png"))
        f.write("set termoption noenhanced\nset logscale xy\nset grid\nset key top right\n")
        f.write("set multiplot layout %d,1 title 'needlesim: speed against accuracy "
                "(tools/speed_accuracy.py)'\n" % len(panels))
        for i, (sc, col, what) in enumerate(panels):
            sel = [r for r in rows if r["scenario"] == sc]
            data = os.path.join(work, "p%d.dat" % i)
            with open(data, "w") as d:
                for r in sel:
                    d.write("%g %g %d \"%s\"\n" % (r["cost_ms_per_s"], max(float(r[col]), 1e-4),
                                                   r["label"] == "default", r["label"]))
                d.write("\n\n")
                key = (lambda r: r["cost_ms_per_s"])
                front = sorted((r for r in sel if r["pareto"] in (True, "True")), key=key)
                for r in front:
                    d.write("%g %g\n" % (r["cost_ms_per_s"], max(float(r["tip_error_mm"]), 1e-4)
                                          if col == "tip_error_mm" else max(float(r[col]), 1e-4)))
            ref = sel[0].get("reference") or "not recorded"
            f.write("set title \"%s\\nreference: %s\"\n" % (what, ref.replace('"', "'")))
            f.write("set xlabel 'cost: wall time per simulated second [ms/s] (median step / dt)'\n")
            f.write("set ylabel '%s'\n" % what.split(": ", 1)[1])
            plots = ["'%s' index 0 using 1:2 with points pt 7 ps 1.2 lc 1 title 'a run (label: the "
                     "settings changed from the defaults)'" % data,
                     "'%s' index 0 using 1:2:4 with labels offset 0.8,0.6 left font ',8' notitle"
                     % data,
                     "'%s' index 0 using ($3 > 0 ? $1 : 1/0):2 with points pt 6 ps 3 "
                     "lc rgb 'black' title 'default settings'" % data]
            if col == "tip_error_mm":
                plots.append("'%s' index 1 using 1:2 with lines lw 2 lc 2 "
                             "title 'Pareto front (cost, this error)'" % data)
            f.write("plot " + ", \\\n     ".join(plots) + "\n")
        f.write("unset multiplot\n")
    subprocess.run(["gnuplot", gp], check=True)
    shutil.rmtree(work, ignore_errors=True)
    print("wrote %s" % os.path.join(out_dir, "speed-accuracy.png"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "needlesim"))
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"))
    ap.add_argument("--only", choices=sorted(SCENARIOS))
    ap.add_argument("--chart-only", action="store_true",
                    help="redraw the chart from the CSV, running nothing")
    a = ap.parse_args()
    if a.chart_only:
        rows = [r for r in csv.DictReader(open(os.path.join(a.out, "speed-accuracy.csv")))
                if not r["failed"]]
        for r in rows:
            r["cost_ms_per_s"] = float(r["cost_ms_per_s"])
        chart(rows, a.out)
        return
    tmp = tempfile.mkdtemp(prefix="needlesim-sweep.")
    rows = []
    try:
        for name, spec in SCENARIOS.items():
            if a.only and name != a.only:
                continue
            print("%s: reference %s ..." % (name, label(spec["reference"])), flush=True)
            ladder = []
            for lv in spec.get("ladder", [None]):
                sets = dict(spec["reference"])
                if lv is not None:
                    sets["tissue.refine"] = lv
                ref, err = run(a.bin, spec["file"], sets, tmp)
                if not ref:
                    sys.exit("%s: the reference run %s failed: %s" % (name, label(sets), err))
                ladder.append(ref)
            if len(ladder) >= 3:
                ref = richardson(ladder, spec["ladder"], a.out)
                ref_name = "Richardson-extrapolated tip path, refine %s, %s" % (
                    "/".join(str(x) for x in spec["ladder"]), label(spec["reference"]))
            else:
                ref = ladder[-1]
                ref_name = "tightest run (%s), not extrapolated" % label(spec["reference"])
            for sets in spec["runs"]:
                full = dict(DEFAULT)
                full.update(sets)
                got, err = run(a.bin, spec["file"], sets, tmp)
                row = {"scenario": name, "label": label(sets), "reference": ref_name,
                       "refine": full["tissue.refine"], "dt": full["dt"],
                       "tolerance": full["solver.tolerance"],
                       "lazy_threshold": full["solver.lazy_threshold"]}
                if not got:
                    print("  %-40s failed: %s" % (row["label"], err), flush=True)
                    row.update({"tets": 0, "steps": 0, "median_step_ms": float("nan"),
                                "cost_ms_per_s": float("nan"), "tip_error_mm": float("nan"),
                                "marker_error_mm": float("nan"), "failed": err})
                    rows.append(row)
                    continue
                rep = got["report"]
                if spec.get("metric") == "seeds":
                    tip, marker = seed_errors(rep, ref["report"]), 0.0
                else:
                    tip, marker = errors(got, ref)
                    if len(ladder) >= 3:  # markers against the finest run of the ladder
                        marker = errors(got, ladder[-1])[1]
                if tip is None or not math.isfinite(tip):
                    err = "%d seeds, the reference %d" % (len(rep["seeds"]),
                                                          len(ref["report"]["seeds"]))
                    print("  %-40s failed: %s" % (row["label"], err), flush=True)
                    row.update({"tets": rep["mesh"]["tets"], "steps": rep["steps"],
                                "median_step_ms": float("nan"), "cost_ms_per_s": float("nan"),
                                "tip_error_mm": float("nan"), "marker_error_mm": float("nan"),
                                "failed": err})
                    rows.append(row)
                    continue
                row.update({"tets": rep["mesh"]["tets"], "steps": rep["steps"],
                            "median_step_ms": rep["step_ms"]["median"],
                            "cost_ms_per_s": rep["step_ms"]["median"] / full["dt"],
                            "tip_error_mm": 1e3 * tip, "marker_error_mm": 1e3 * marker,
                            "failed": ""})
                rows.append(row)
                print("  %-40s %6d tets  %7.2f ms/step  %8.0f ms/s  tip %.3f mm  markers %.3f mm"
                      % (row["label"], row["tets"], row["median_step_ms"], row["cost_ms_per_s"],
                         row["tip_error_mm"], row["marker_error_mm"]), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    # rows of scenarios not swept this time (--only) come from the last CSV
    path = os.path.join(a.out, "speed-accuracy.csv")
    swept = {r["scenario"] for r in rows}
    if os.path.exists(path):
        for old in csv.DictReader(open(path)):
            if old["scenario"] in swept:
                continue
            for k in ["refine", "dt", "tolerance", "lazy_threshold", "median_step_ms",
                      "cost_ms_per_s", "tip_error_mm", "marker_error_mm"]:
                old[k] = float(old[k])
            for k in ["tets", "steps"]:
                old[k] = int(old[k])
            rows.append(old)
    ok = [r for r in rows if not r["failed"]]
    for sc in {r["scenario"] for r in ok}:
        pareto([r for r in ok if r["scenario"] == sc])
    for r in rows:
        r.setdefault("pareto", False)
    os.makedirs(a.out, exist_ok=True)
    keys = ["scenario", "label", "refine", "tets", "dt", "tolerance", "lazy_threshold", "steps",
            "median_step_ms", "cost_ms_per_s", "tip_error_mm", "marker_error_mm", "pareto",
            "reference", "failed"]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    print("wrote %s" % path)
    write_fronts(ok)
    chart(ok, a.out)


if __name__ == "__main__":
    main()
