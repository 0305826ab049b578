#!/usr/bin/env python3
"""Stability map (issue 9, docs/performance.md).

Runs tools/stability.lua (a stiff needle into a gel block) over a grid of time step,
needle/tissue stiffness ratio (the gel's Young's modulus), insertion speed and motion (steady,
or vigorously back and forth), with our solver and the paper's, and records for each cell:
whether the run failed (a NaN, a blow-up, a failed remesh: the run's own error), the NaN,
inverted and unconverged counts, the fraction of steps whose friction states stayed
unresolved, the worst dihedral angle near the needle, and the tip's lateral error (the needle
should stay on its line). Writes docs/stability.csv, docs/stability.png (gnuplot) and prints
the table docs/performance.md holds.

    python3 tools/stability_map.py [--bin build/needlesim] [--out docs]

A benchmark, not a test (about a quarter of an hour on the 2-core machine).
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
NEEDLE_E = 200e9  # the stiff needle's steel (scripts/needlesim.lua)

DTS = [0.005, 0.01, 0.02, 0.05]
YOUNGS = [2e3, 20e3, 200e3]
SPEEDS = [0.02, 0.2]
MOTIONS = [False, True]
SOLVERS = ["schur", "paper"]


def cell(binary, tmp, solver, dt, youngs, speed, vigorous):
    out = tempfile.mkdtemp(dir=tmp)
    cmd = [binary, "run", SCENE, "--no-render", "--quiet", "-o", out, "--solver", solver,
           "--set", "dt=%r" % dt, "--set", "youngs=%r" % youngs, "--set", "speed=%r" % speed,
           "--set", "vigorous=%s" % ("true" if vigorous else "false")]
    p = subprocess.run(cmd, capture_output=True, text=True)
    row = {"solver": solver, "dt": dt, "youngs": youngs, "stiffness_ratio": NEEDLE_E / youngs,
           "speed": speed, "motion": "vigorous" if vigorous else "steady"}
    if p.returncode != 0:
        msg = p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "exit %d" % p.returncode
        # the reason, without the scenario path and step details
        reason = msg.split("failed: ", 1)[-1] if "failed: " in msg else msg
        row.update({"status": "failed", "reason": reason[:120], "steps": 0, "nan": "",
                    "inverted": "", "unconverged": "", "lcp_unresolved_fraction": "",
                    "min_dihedral_deg": "", "tip_error_mm": "", "median_step_ms": ""})
        shutil.rmtree(out)
        return row
    rep = json.load(open(os.path.join(out, "report.json")))
    rows = list(csv.reader(open(os.path.join(out, "trajectory.csv"))))[1:]
    shutil.rmtree(out)
    lateral = max(math.hypot(float(r[1]), float(r[2])) for r in rows)
    w = rep["warnings"]
    frac = w["lcp_unresolved"] / max(1, rep["steps"])
    status, reason = "ok", ""
    if w["nan"] or w["inverted"] or lateral > 2e-3:
        status = "unstable"
        reason = "NaN %d, inverted %d, tip off its line by %.2f mm" % (w["nan"], w["inverted"],
                                                                       1e3 * lateral)
    elif frac > 0.05 or w["unconverged"] or rep["mesh"]["min_dihedral_deg"] < 5.0:
        status = "degraded"
        reason = "friction unresolved %.0f %% of steps, unconverged %d, worst dihedral %.1f deg" % (
            100 * frac, w["unconverged"], rep["mesh"]["min_dihedral_deg"])
    row.update({"status": status, "reason": reason, "steps": rep["steps"], "nan": w["nan"],
                "inverted": w["inverted"], "unconverged": w["unconverged"],
                "lcp_unresolved_fraction": frac,
                "min_dihedral_deg": rep["mesh"]["min_dihedral_deg"],
                "tip_error_mm": 1e3 * lateral, "median_step_ms": rep["step_ms"]["median"]})
    return row


def chart(rows, out_dir):
    if not shutil.which("gnuplot"):
        print("gnuplot not found (apt install gnuplot-nox): no chart", file=sys.stderr)
        return
    colour = {"ok": 0x2ca02c, "degraded": 0xff9f1c, "unstable": 0xd62728, "failed": 0x5a0f14}
    work = tempfile.mkdtemp(prefix="needlesim-chart.")  # gnuplot's input, removed after
    data = os.path.join(work, "stability.dat")
    ylabels = []
    with open(data, "w") as f:
        for si, solver in enumerate(SOLVERS):
            y = 0
            for youngs in YOUNGS:
                for speed in SPEEDS:
                    for vig in MOTIONS:
                        if si == 0:
                            ylabels.append("E %g kPa, %g mm/s, %s" % (
                                youngs / 1e3, 1e3 * speed, "vigorous" if vig else "steady"))
                        for xi, dt in enumerate(DTS):
                            r = next(r for r in rows if r["solver"] == solver and r["dt"] == dt
                                     and r["youngs"] == youngs and r["speed"] == speed
                                     and r["motion"] == ("vigorous" if vig else "steady"))
                            f.write("%d %d %d\n" % (xi + si * (len(DTS) + 1), y,
                                                    colour[r["status"]]))
                        y += 1
            f.write("\n")
    gp = os.path.join(work, "stability.gp")
    xt = ", ".join("'%g' %d" % (1e3 * dt, xi + si * (len(DTS) + 1))
                   for si in range(len(SOLVERS)) for xi, dt in enumerate(DTS))
    yt = ", ".join("'%s' %d" % (l, i) for i, l in enumerate(ylabels))
    with open(gp, "w") as f:
        f.write("set terminal pngcairo size 1200,720 font 'DejaVu Sans,11'\n")
        f.write("set output '%s'\n" % os.path.join(out_dir, "stability.png"))
        f.write("set xtics (%s)\nset ytics (%s)\n" % (xt, yt))
        f.write("set xrange [-0.6:%g]\nset yrange [-0.6:%g]\n" % (
            len(SOLVERS) * (len(DTS) + 1) - 1.4, len(ylabels) - 0.4))
        f.write("set xlabel 'time step [ms]: our solver (left), the paper''s (right)'\n")
        f.write("set title 'needlesim stability map (tools/stability_map.py): green ok, orange "
                "degraded, red unstable, dark red failed'\n")
        f.write("set termoption noenhanced\nunset key\nset lmargin 30\n")
        f.write("plot '%s' using 1:2:3 with points pt 5 ps 5 lc rgb variable\n" % data)
    subprocess.run(["gnuplot", gp], check=True)
    shutil.rmtree(work, ignore_errors=True)
    print("wrote %s" % os.path.join(out_dir, "stability.png"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "needlesim"))
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"))
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="needlesim-stability.")
    rows = []
    try:
        for solver in SOLVERS:
            for youngs in YOUNGS:
                for speed in SPEEDS:
                    for vig in MOTIONS:
                        for dt in DTS:
                            r = cell(a.bin, tmp, solver, dt, youngs, speed, vig)
                            rows.append(r)
                            print("%-6s dt %5.3f E %6.0f v %.2f %-8s %-8s %s" % (
                                solver, dt, youngs, speed, r["motion"], r["status"],
                                r["reason"]), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(a.out, exist_ok=True)
    keys = ["solver", "dt", "youngs", "stiffness_ratio", "speed", "motion", "status", "reason",
            "steps", "nan", "inverted", "unconverged", "lcp_unresolved_fraction",
            "min_dihedral_deg", "tip_error_mm", "median_step_ms"]
    path = os.path.join(a.out, "stability.csv")
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow(r)
    print("wrote %s" % path)
    print("\n| solver | ok | degraded | unstable | failed |\n|---|---|---|---|---|")
    for s in SOLVERS:
        sel = [r for r in rows if r["solver"] == s]
        print("| %s | %s |" % (s, " | ".join(str(sum(r["status"] == k for r in sel))
                                           for k in ["ok", "degraded", "unstable", "failed"])))
    chart(rows, a.out)


if __name__ == "__main__":
    main()
