#!/usr/bin/env python3
"""Stability map (issues 9 and 35, docs/performance.md).

Runs tools/stability.lua (a needle into a gel block along its centre line) over a grid of time
step, the gel's Young's modulus (the needle/tissue stiffness ratio), insertion speed, motion
(steady, or vigorously back and forth) and needle (the stiff symmetric one, the flexible bevel
one), with our solver and the paper's, and records for each cell its status, the NaN, inverted
and unconverged counts, the fraction of steps whose friction states stayed unresolved, the worst
dihedral angle, and the tip's lateral offset from the centre line. Statuses:

  ok          none of the below
  recovered   inverted elements, which the invertible FEM recovered, and the result unaffected:
              the tip path within RECOVERED_TIP_MM and the tissue's final energy within
              RECOVERED_ENERGY of the same cell at half the time step (the check's figures are
              in the csv)
  degraded    friction unresolved in > 5 % of steps, an unconverged solve, a dihedral < 5 deg
  unstable    a NaN; the tip off its line by > 2 mm (stiff) or > 10 mm (flexible: its bevel
              steers it ~5 mm off over 3 cm); inverted elements that change the result
  unmodelled  the run stopped at a named event the simulator does not model (its message says
              "not modelled")
  failed      the run stopped with any other error

Writes docs/stability.csv, docs/stability.png (gnuplot) and prints the table docs/performance.md
holds.

    python3 tools/stability_map.py [--bin build/needlesim] [--out docs] [--solvers schur,paper]
        [--needles stiff,flexible] [--merge CSV...]

--merge adds the rows of earlier runs' csv files (those of a solver and needle measured now are
dropped), so that the map can be made in parts (`--solvers "" --merge A.csv B.csv` only
merges, tabulates and charts).

A benchmark, not a test (about an hour on the 2-core machine for both solvers; run it niced).
"""
import argparse
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, "tools", "stability.lua")
NEEDLE_E = {"stiff": 200e9, "flexible": 50e9}  # steel, nitinol (scripts/needlesim.lua)

DTS = [0.005, 0.01, 0.02, 0.05]
YOUNGS = [1e3, 2e3, 5e3, 20e3, 200e3]
SPEEDS = [0.02, 0.2]
MOTIONS = [False, True]
NEEDLES = ["stiff", "flexible"]
SOLVERS = ["schur", "paper"]
STATUSES = ["ok", "recovered", "degraded", "unstable", "unmodelled", "failed"]
LATERAL_MM = {"stiff": 2.0, "flexible": 10.0}
RECOVERED_TIP_MM = 1.0  # a fifth of the gel's 5 mm elements
RECOVERED_ENERGY = 0.1


def run_cell(binary, tmp, solver, dt, youngs, speed, vigorous, needle):
    """One run: (error message or None, report, trajectory rows)."""
    out = tempfile.mkdtemp(dir=tmp)
    cmd = [binary, "run", SCENE, "--no-render", "--quiet", "-o", out, "--solver", solver,
           "--set", "dt=%r" % dt, "--set", "youngs=%r" % youngs, "--set", "speed=%r" % speed,
           "--set", "vigorous=%s" % ("true" if vigorous else "false"), "--set",
           "needle=%s" % needle]
    p = subprocess.run(cmd, capture_output=True, text=True)
    try:
        if p.returncode != 0:
            msg = p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "exit %d" % p.returncode
            # the reason, without the scenario path and step details
            return (msg.split("failed: ", 1)[-1] if "failed: " in msg else msg), None, None
        rep = json.load(open(os.path.join(out, "report.json")))
        rows = [[float(v) for v in r[:5]]
                for r in list(csv.reader(open(os.path.join(out, "trajectory.csv"))))[1:]]
        return None, rep, rows
    finally:
        shutil.rmtree(out)


def finer_check(binary, tmp, solver, dt, youngs, speed, vigorous, needle, rep, rows):
    """The cell at dt / 2: the largest tip distance at the common times [mm] and the tissue's
    final energy's relative difference, or None when the finer run failed."""
    err, rep2, rows2 = run_cell(binary, tmp, solver, dt / 2, youngs, speed, vigorous, needle)
    if err is not None:
        return None
    fine = {round(r[0] / dt * 2): r for r in rows2}
    d = 0.0
    for r in rows:
        f = fine.get(round(r[0] / dt * 2))
        if f is not None:
            d = max(d, math.dist(r[1:4], f[1:4]))
    e1, e2 = rep["mesh"]["tissue_energy_j"], rep2["mesh"]["tissue_energy_j"]
    de = abs(e1 - e2) / max(abs(e1), abs(e2), 1e-12)
    return 1e3 * d, de


def cell(binary, tmp, solver, dt, youngs, speed, vigorous, needle):
    row = {"solver": solver, "needle": needle, "dt": dt, "youngs": youngs,
           "stiffness_ratio": NEEDLE_E[needle] / youngs, "speed": speed,
           "motion": "vigorous" if vigorous else "steady"}
    err, rep, rows = run_cell(binary, tmp, solver, dt, youngs, speed, vigorous, needle)
    if err is not None:
        row.update({"status": "unmodelled" if "not modelled" in err else "failed",
                    "reason": err[:160], "steps": 0})
        return row
    lateral = max(math.hypot(r[1], r[2]) for r in rows)
    w = rep["warnings"]
    frac = w["lcp_unresolved"] / max(1, rep["steps"])
    status, reason = "ok", ""
    finer = None
    if w["inverted"] and not w["nan"]:
        finer = finer_check(binary, tmp, solver, dt, youngs, speed, vigorous, needle, rep, rows)
    if w["nan"] or 1e3 * lateral > LATERAL_MM[needle]:
        status = "unstable"
        reason = "NaN %d, inverted %d, tip off its line by %.2f mm" % (w["nan"], w["inverted"],
                                                                       1e3 * lateral)
    elif w["inverted"] and (finer is None or finer[0] > RECOVERED_TIP_MM
                            or finer[1] > RECOVERED_ENERGY):
        status = "unstable"
        reason = "inverted %d; at dt/2 %s" % (
            w["inverted"], "the run failed" if finer is None else
            "the tip path differs by %.2f mm, the energy by %.0f %%" % (finer[0], 100 * finer[1]))
    elif w["inverted"]:
        status = "recovered"
        reason = "inverted %d, recovered: at dt/2 the tip path within %.3f mm, the energy " \
                 "within %.1f %%" % (w["inverted"], finer[0], 100 * finer[1])
    elif frac > 0.05 or w["unconverged"] or rep["mesh"]["min_dihedral_deg"] < 5.0:
        status = "degraded"
        reason = "friction unresolved %.0f %% of steps, unconverged %d, worst dihedral %.1f deg" % (
            100 * frac, w["unconverged"], rep["mesh"]["min_dihedral_deg"])
    events = [e["type"] for e in rep["events"]]
    row.update({"status": status, "reason": reason, "steps": rep["steps"], "nan": w["nan"],
                "inverted": w["inverted"], "unconverged": w["unconverged"],
                "lcp_unresolved_fraction": frac,
                "min_dihedral_deg": rep["mesh"]["min_dihedral_deg"],
                "tip_error_mm": 1e3 * lateral, "median_step_ms": rep["step_ms"]["median"],
                "finer_tip_mm": "" if finer is None else finer[0],
                "finer_energy_rel": "" if finer is None else finer[1],
                "events": " ".join(events)})
    return row


# Okabe-Ito (colour-blind safe), one colour per status, and a marker shape per status too.
COLOUR = {"ok": 0x009E73, "recovered": 0x56B4E9, "degraded": 0xE69F00, "unstable": 0xD55E00,
          "unmodelled": 0xCC79A7, "failed": 0x000000}
SHAPE = {"ok": 5, "recovered": 7, "degraded": 9, "unstable": 11, "unmodelled": 13, "failed": 3}


def chart(rows, solvers, out_dir):
    if not shutil.which("gnuplot"):
        print("gnuplot not found (apt install gnuplot-nox): no chart", file=sys.stderr)
        return
    work = tempfile.mkdtemp(prefix="needlesim-chart.")  # gnuplot's input, removed after
    ylabels = []
    for needle in NEEDLES:
        for youngs in YOUNGS:
            for speed in SPEEDS:
                for vig in MOTIONS:
                    ylabels.append("%s, E %g kPa, %g mm/s, %s" % (
                        needle, youngs / 1e3, 1e3 * speed, "vigorous" if vig else "steady"))
    pts = {k: [] for k in STATUSES}
    y = 0
    for needle in NEEDLES:
        for youngs in YOUNGS:
            for speed in SPEEDS:
                for vig in MOTIONS:
                    for si, solver in enumerate(solvers):
                        for xi, dt in enumerate(DTS):
                            r = next((r for r in rows if r["solver"] == solver and r["dt"] == dt
                                      and r["youngs"] == youngs and r["speed"] == speed
                                      and r["needle"] == needle
                                      and r["motion"] == ("vigorous" if vig else "steady")), None)
                            if r is not None:
                                pts[r["status"]].append((xi + si * (len(DTS) + 1), y))
                    y += 1
    gp = os.path.join(work, "stability.gp")
    xt = ", ".join("'%g' %d" % (1e3 * dt, xi + si * (len(DTS) + 1))
                   for si in range(len(solvers)) for xi, dt in enumerate(DTS))
    yt = ", ".join("'%s' %d" % (l, i) for i, l in enumerate(ylabels))
    names = " and ".join("%s (%s)" % ("ours" if s == "schur" else "the paper's", s) for s in solvers)
    with open(gp, "w") as f:
        f.write("set terminal pngcairo size 1300,%d font 'DejaVu Sans,10'\n" % (
            160 + 18 * len(ylabels)))
        f.write("set output '%s'\n" % os.path.join(out_dir, "stability.png"))
        f.write("set xtics (%s)\nset ytics (%s)\n" % (xt, yt))
        f.write("set xrange [-0.6:%g]\nset yrange [-0.6:%g]\n" % (
            len(solvers) * (len(DTS) + 1) - 1.4, len(ylabels) - 0.4))
        f.write("set xlabel 'time step [ms]: %s, left to right'\n" % names)
        f.write("set title 'needlesim stability map (tools/stability_map.py)'\n")
        f.write("set termoption noenhanced\nset lmargin 38\nset rmargin 18\n")
        f.write("set key outside right top box width 2 title 'status'\n")
        plots = []
        for k in STATUSES:
            data = os.path.join(work, "%s.dat" % k)
            with open(data, "w") as d:
                for x, yy in pts[k] or [(-10, -10)]:  # an empty status keeps its legend entry
                    d.write("%d %d\n" % (x, yy))
            plots.append("'%s' using 1:2 with points pt %d ps 2.2 lc rgb '#%06X' title '%s'" % (
                data, SHAPE[k], COLOUR[k], k))
        f.write("plot " + ", \\\n     ".join(plots) + "\n")
    subprocess.run(["gnuplot", gp], check=True)
    shutil.rmtree(work, ignore_errors=True)
    print("wrote %s" % os.path.join(out_dir, "stability.png"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "needlesim"))
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"))
    ap.add_argument("--solvers", default=",".join(SOLVERS),
                    help="comma-separated: schur, paper (default both)")
    ap.add_argument("--needles", default=",".join(NEEDLES),
                    help="comma-separated: stiff, flexible (default both)")
    ap.add_argument("--merge", nargs="*", default=[],
                    help="csv files of earlier runs (other solvers or needles) to chart and "
                         "tabulate with this one")
    a = ap.parse_args()
    solvers = [x for x in a.solvers.split(",") if x]
    needles = [x for x in a.needles.split(",") if x]
    tmp = tempfile.mkdtemp(prefix="needlesim-stability.")
    rows = []
    try:
        for solver in solvers:
            for needle in needles:
                for youngs in YOUNGS:
                    for speed in SPEEDS:
                        for vig in MOTIONS:
                            for dt in DTS:
                                r = cell(a.bin, tmp, solver, dt, youngs, speed, vig, needle)
                                rows.append(r)
                                print("%-6s %-8s dt %5.3f E %6.0f v %.2f %-8s %-10s %s" % (
                                    solver, needle, dt, youngs, speed, r["motion"], r["status"],
                                    r["reason"]), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(a.out, exist_ok=True)
    keys = ["solver", "needle", "dt", "youngs", "stiffness_ratio", "speed", "motion", "status",
            "reason", "steps", "nan", "inverted", "unconverged", "lcp_unresolved_fraction",
            "min_dihedral_deg", "tip_error_mm", "median_step_ms", "finer_tip_mm",
            "finer_energy_rel", "events"]
    measured = {(q["solver"], q["needle"]) for q in rows}
    for m in a.merge:  # the earlier rows (read before the csv is written: it may be one of them)
        for r in csv.DictReader(open(m)):
            if (r["solver"], r["needle"]) in measured:
                continue  # measured again now
            for k in ("dt", "youngs", "speed"):
                r[k] = float(r[k])
            rows.append(r)
            if r["solver"] not in solvers:
                solvers.append(r["solver"])
    solvers.sort(key=SOLVERS.index)
    rows.sort(key=lambda r: (SOLVERS.index(r["solver"]), NEEDLES.index(r["needle"]),
                             YOUNGS.index(r["youngs"]), SPEEDS.index(r["speed"]),
                             r["motion"] == "vigorous", DTS.index(r["dt"])))
    path = os.path.join(a.out, "stability.csv")
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys, restval="")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    print("wrote %s" % path)
    print("\n| solver | needle | %s |\n|---|---|%s" % (" | ".join(STATUSES), "---|" * len(STATUSES)))
    for s in solvers:
        for n in NEEDLES:
            sel = [r for r in rows if r["solver"] == s and r["needle"] == n]
            print("| %s | %s | %s |" % (s, n, " | ".join(str(sum(r["status"] == k for r in sel))
                                                         for k in STATUSES)))
    chart(rows, solvers, a.out)


if __name__ == "__main__":
    main()
