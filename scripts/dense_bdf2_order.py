#!/usr/bin/env python3
"""BDF2's order in time in a dense suspension: one packed scene run at a ladder of dt and
compared with a run at a finer dt (issue 51: "BDF2 keeps its second order in a dense
suspension").

    scripts/dense_bdf2_order.py --binary target/release/mobo --out /tmp/order \
        [--count 8] [--phi 0.3] [--gap 0.1] [--order 8] [--viscosity-ratio 5] \
        [--coupling near_implicit] [--contact 0] [--t-end 0.4] \
        [--dts 0.04,0.02,0.01,0.005] [--reference 0.0025] [--gmres-tol 1e-9] [--fmm-digits 6] [--upsample 2]

The scene: `count` RBCs (Skalak, shear modulus 1, bending 0.1) packed at volume fraction `phi`
with surfaces at least `gap` apart (`placement = "packed"`, seed 7), shear rate 1, BDF2. The
error of a run is the largest difference of the final shape coefficients from the reference
run's, over all cells, relative to the largest coefficient; the centroid error is the largest
distance between a cell's final centroid and the reference's. Contacts are off by default
(`--contact 0`): a projection move is not smooth in dt, and the table counts the moves of each
run so that a run where they acted is seen. Prints a Markdown table. Needs numpy.
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np


def scene(a, dt):
    # One cell (--count 1): the same RBC alone, tilted, the cell step's own order.
    place = ('orientation = [0.3, 1.0, 0.5, 40.0]\n' if a.count == 1 else
             f'count = {a.count}\nplacement = "packed"\nvolume_fraction = {a.phi}\n'
             f'min_gap = {a.gap}\nseed = 7\n')
    return f"""[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
{place}bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = {a.viscosity_ratio}
[numerics]
order = {a.order}
dt = {dt}
t_end = {a.t_end}
scheme = "bdf2"
coupling = "{a.coupling}"
contact_distance = {a.contact}
gmres_tol = {a.gmres_tol}
fmm_digits = {a.fmm_digits}
upsample = {a.upsample}
[output]
every = {int(round(a.t_end / dt))}
vtk = false
"""


def run(a, dt):
    out = os.path.join(a.out, f"dt{dt:g}")
    if not os.path.exists(os.path.join(out, "summary.json")):
        os.makedirs(a.out, exist_ok=True)
        path = os.path.join(a.out, f"dt{dt:g}.toml")
        with open(path, "w") as f:
            f.write(scene(a, dt))
        r = subprocess.run([a.binary, "run", path, "--out", out, "--quiet"],
                           capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"dt = {dt}: mobo run failed:\n{r.stderr}")
    s = json.load(open(os.path.join(out, "summary.json")))
    if not s.get("completed", False):
        sys.exit(f"dt = {dt}: the run did not complete: {s.get('error')}")
    times = np.load(os.path.join(out, "frames", "times.npy"))
    last = len(times) - 1
    if abs(times[last] - a.t_end) > 1e-9:
        sys.exit(f"dt = {dt}: the last frame is at t = {times[last]}, not {a.t_end}")
    coefs = np.load(os.path.join(out, "frames", f"frame_{last:05d}_coefs.npy"))
    pos = np.load(os.path.join(out, "frames", f"frame_{last:05d}_positions.npy"))
    moves = s.get("counters", {}).get("contacts", {}).get("moves", 0)
    step_s = s.get("step_s", float("nan")) / max(s.get("steps", 1), 1)
    return coefs, pos.mean(axis=2), moves, step_s, s.get("min_gap")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--binary", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--count", type=int, default=8)
    p.add_argument("--phi", type=float, default=0.3)
    p.add_argument("--gap", type=float, default=0.1)
    p.add_argument("--order", type=int, default=8)
    p.add_argument("--viscosity-ratio", type=float, default=5.0)
    p.add_argument("--coupling", default="near_implicit")
    p.add_argument("--contact", type=float, default=0.0)
    p.add_argument("--t-end", type=float, default=0.4)
    p.add_argument("--gmres-tol", type=float, default=1e-9)
    p.add_argument("--fmm-digits", type=int, default=6)
    p.add_argument("--upsample", type=int, default=2)
    p.add_argument("--dts", default="0.04,0.02,0.01,0.005")
    p.add_argument("--reference", type=float, default=0.0025)
    a = p.parse_args()
    dts = [float(x) for x in a.dts.split(",")]
    ref_c, ref_x, ref_moves, ref_s, ref_gap = run(a, a.reference)
    scale = np.abs(ref_c).max()
    print(f"{a.count} RBCs at {a.phi:.0%} (gap {a.gap}), λ = {a.viscosity_ratio}, "
          f"p = {a.order}, {a.coupling}, contact_distance = {a.contact}, t = {a.t_end}, "
          f"gmres_tol = {a.gmres_tol}, fmm_digits = {a.fmm_digits}, upsample = {a.upsample}; "
          f"reference Δt = {a.reference} (contact moves {ref_moves}, smallest gap "
          f"{ref_gap})\n")
    print("| Δt | shape error | order | centroid error | order | contact moves | s a step |")
    print("|---|---|---|---|---|---|---|")
    prev = None
    for dt in dts:
        c, x, moves, step_s, _ = run(a, dt)
        e = np.abs(c - ref_c).max() / scale
        ex = np.linalg.norm(x - ref_x, axis=1).max()
        if prev is None:
            o, ox = "–", "–"
        else:
            r = prev[0] / dt
            o = f"{np.log(prev[1] / e) / np.log(r):.2f}"
            ox = f"{np.log(prev[2] / ex) / np.log(r):.2f}"
        print(f"| {dt:g} | {e:.3e} | {o} | {ex:.3e} | {ox} | {moves} | {step_s:.2f} |")
        prev = (dt, e, ex)


if __name__ == "__main__":
    main()
