#!/usr/bin/env python3
"""Tube hematocrit, Fåhræus ratio and cell-free layer of a recycled tube run, against Pries et al.

    python3 scripts/blood_in_tube.py OUT [--cell-radius-um 2.8] [--every-rows 10] [--svg FILE]

OUT is the output folder of `mobo run` on a scene with `[flow] kind = "tube"`, `recycle = true`
and a tube container (docs/walls.md). Frames must be written (`[output] every`); the script
reads `OUT/scene.toml` and `OUT/frames/*.npy` and prints, over consecutive blocks of frames:

* the cells whose centre lies in the window (the tube's straight section, where its radius is
  within 1e-3 of R: the window the cells are recycled through);
* the tube hematocrit H_T: those cells' volume (each the volume of a sphere of the cells' radius,
  the equivalent radius) over the window's volume pi R^2 L_w;
* the cells' mean axial speed <U_c> over the mean flow speed u_mean = U/2 (recycling moves are
  undone when the speed is measured);
* the Fåhræus ratio H_T/H_D = u_mean/<U_c> (the cells' flux through a cross-section is
  H_T <U_c> pi R^2 = H_D Q, Q = u_mean pi R^2);
* the cell-free layer: R less the largest distance of a membrane point (of a cell in the
  window) from the axis, averaged over the block's frames.

A check of the Fåhræus ratio by the cells' flux follows the table: H_D from the cells' centres
crossing seven planes across the window between frames (the recycling's jumps unwrapped) over
the second half of the run, against the mean of the table's rows there.

* the relative apparent viscosity mu_app/mu of the tube's straight section, averaged over the
  block's steps: the `relative_viscosity` column of OUT/observables.csv, 1 + (P - P_0)/(Q G L),
  the cells' extra dissipation by the reciprocal theorem over the flow rate times the pressure
  drop of the section without cells (docs/walls.md).

And, for the tube's diameter in micrometres (D = 2R times the cell radius in um) and the
measured H_D, the in-vitro fits of Pries et al. (Circ. Res. 67, 1990; Am. J. Physiol. 263,
1992): H_T/H_D = H_D + (1 - H_D)(1 + 1.7 e^(-0.415 D) - 0.6 e^(-0.011 D)), and
mu_rel = 1 + (mu_0.45 - 1)((1 - H_D)^C - 1)/((1 - 0.45)^C - 1) with
mu_0.45 = 220 e^(-1.3 D) + 3.2 - 2.44 e^(-0.06 D^0.645) and
C = (0.8 + e^(-0.075 D))(-1 + 1/(1 + 1e-11 D^12)) + 1/(1 + 1e-11 D^12).
"""

import argparse
import glob
import math
import os
import sys
import tomllib

import numpy as np

TOLERANCE = 1e-3  # scene::TUBE_WINDOW_TOLERANCE
EXPONENT = 6  # wall::TUBE_END_EXPONENT


def pries_ht_over_hd(d_um, hd):
    return hd + (1 - hd) * (1 + 1.7 * math.exp(-0.415 * d_um) - 0.6 * math.exp(-0.011 * d_um))


def pries_mu_rel(d_um, hd):
    mu45 = 220 * math.exp(-1.3 * d_um) + 3.2 - 2.44 * math.exp(-0.06 * d_um**0.645)
    w = 1 / (1 + 1e-11 * d_um**12)
    c = (0.8 + math.exp(-0.075 * d_um)) * (-1 + w) + w
    return 1 + (mu45 - 1) * ((1 - hd) ** c - 1) / ((1 - 0.45) ** c - 1)


def relative_viscosity(out):
    """(time, relative_viscosity) rows of OUT/observables.csv (none in older tables)."""
    path = os.path.join(out, "observables.csv")
    if not os.path.exists(path):
        return np.zeros((0, 2))
    lines = open(path).read().splitlines()
    head = lines[0].split(",")
    if "relative_viscosity" not in head:
        return np.zeros((0, 2))
    it, iv = head.index("time"), head.index("relative_viscosity")
    rows = []
    for line in lines[1:]:
        f = line.split(",")
        if len(f) > iv and f[iv]:
            rows.append((float(f[it]), float(f[iv])))
    return np.array(rows).reshape(-1, 2)


def svg(path, mu_rows, blocks, pries_mu, pries_ratio):
    """mu_app/mu per step and H_T/H_D per block against time, with Pries' values (dashed)."""
    w, h, m = 640, 400, 60
    t1 = max(mu_rows[-1, 0] if len(mu_rows) else 0, blocks[-1][0] if blocks else 0) or 1
    values = list(mu_rows[:, 1]) + [b[1] for b in blocks] + [pries_mu, pries_ratio]
    lo, hi = min(values) - 0.05, max(values) + 0.05
    x = lambda t: m + (w - 2 * m) * t / t1
    y = lambda v: h - m - (h - 2 * m) * (v - lo) / (hi - lo)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" '
           f'font-family="sans-serif" font-size="12">',
           f'<rect width="{w}" height="{h}" fill="white"/>',
           f'<line x1="{m}" y1="{h - m}" x2="{w - m}" y2="{h - m}" stroke="black"/>',
           f'<line x1="{m}" y1="{m}" x2="{m}" y2="{h - m}" stroke="black"/>',
           f'<text x="{w / 2}" y="{h - 20}" text-anchor="middle">t (the run\'s '
           f'time unit)</text>']
    for k in range(6):
        v = lo + (hi - lo) * k / 5
        out.append(f'<text x="{m - 6}" y="{y(v) + 4:.1f}" text-anchor="end">{v:.2f}</text>')
        t = t1 * k / 5
        out.append(f'<text x="{x(t):.1f}" y="{h - m + 16}" text-anchor="middle">{t:.1f}</text>')
    if len(mu_rows):
        pts = " ".join(f"{x(t):.1f},{y(v):.1f}" for t, v in mu_rows)
        out.append(f'<polyline points="{pts}" fill="none" stroke="#1f5fbf" stroke-width="1.5"/>')
    for t, v in blocks:
        out.append(f'<circle cx="{x(t):.1f}" cy="{y(v):.1f}" r="3" fill="#c0392b"/>')
    for v, colour in [(pries_mu, "#1f5fbf"), (pries_ratio, "#c0392b")]:
        out.append(f'<line x1="{m}" y1="{y(v):.1f}" x2="{w - m}" y2="{y(v):.1f}" '
                   f'stroke="{colour}" stroke-dasharray="6,4"/>')
    out.append(f'<text x="{m + 8}" y="{m - 24}" fill="#1f5fbf">mu_app/mu per step (line); '
               f'Pries et al. mu_rel at the mean H_D (dashed)</text>')
    out.append(f'<text x="{m + 8}" y="{m - 8}" fill="#c0392b">H_T/H_D per block (dots); '
               f'Pries et al. at the mean H_D (dashed)</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--cell-radius-um", type=float, default=2.8)
    ap.add_argument("--every-rows", type=int, default=10, help="frames per printed block")
    ap.add_argument("--svg", help="write a plot of mu_app/mu and H_T/H_D against time")
    a = ap.parse_args()
    scene = tomllib.load(open(os.path.join(a.out, "scene.toml"), "rb"))
    tube = [w for w in scene.get("walls", []) if w.get("shape") == "tube"]
    if not tube:
        sys.exit(f"{a.out}/scene.toml: no tube wall")
    tube = tube[0]
    radius, length = tube["radius"], tube["length"]
    xc = tube.get("center", [0.0, 0.0, 0.0])[0]
    flow = scene.get("flow", {})
    mu = scene.get("fluid", {}).get("viscosity", 1.0)
    if "speed" in flow:
        u_centre = flow["speed"]
    elif "mean_speed" in flow:
        u_centre = 2 * flow["mean_speed"]
    elif "flow_rate" in flow:
        u_centre = 2 * flow["flow_rate"] / (math.pi * radius**2)
    elif "pressure_gradient" in flow:
        u_centre = flow["pressure_gradient"] * radius**2 / (4 * mu)
    else:
        sys.exit(f"{a.out}/scene.toml: not a tube flow")
    u_mean = u_centre / 2
    half = 0.5 * length * (1 - (1 - TOLERANCE) ** EXPONENT) ** (1 / EXPONENT)
    period = 2 * half
    cell_radius = scene["cells"][0].get("radius", 1.0)
    v_cell = 4 / 3 * math.pi * cell_radius**3
    v_window = math.pi * radius**2 * period

    frames = sorted(glob.glob(os.path.join(a.out, "frames", "frame_*_positions.npy")))
    times = np.load(os.path.join(a.out, "frames", "times.npy"))
    if len(frames) < 2:
        sys.exit(f"{a.out}: fewer than two frames")
    s = math.sqrt(4 * math.pi)
    rows = []
    crossings = []
    planes = np.linspace(-0.88 * half, 0.88 * half, 7)
    prev = None
    for k, f in enumerate(frames):
        pos = np.load(f)  # (cells, 3, points)
        coefs = np.load(f.replace("_positions", "_coefs"))
        centre = coefs[:, :, 0] / s  # c_00 / sqrt(4 pi): the recycling's centre
        inside = np.abs(centre[:, 0] - xc) <= half
        r_max = np.sqrt(pos[:, 1, :] ** 2 + pos[:, 2, :] ** 2).max(axis=1)
        speed = np.nan
        if prev is not None:
            dt = times[k] - prev[0]
            dx = centre[:, 0] - prev[1][:, 0]
            dx = np.where(dx < -0.5 * period, dx + period, dx)  # undo the recycling moves
            both = inside & prev[2]
            if both.any() and dt > 0:
                speed = float(np.mean(dx[both]) / dt)
        rows.append((times[k], int(inside.sum()), speed,
                     float(r_max[inside].max()) if inside.any() else np.nan))
        if prev is not None:
            # Crossings of the planes (and their images one window away) by the unwrapped path.
            a0, e0 = prev[1][:, 0] - xc, prev[1][:, 0] - xc + dx
            c = [int(np.sum((a0 < q) & (e0 >= q)) - np.sum((a0 >= q) & (e0 < q)))
                 for p in planes for q in (p - period, p, p + period)]
            crossings.append((prev[0], times[k], sum(c) / len(planes)))
        prev = (times[k], centre, inside)

    d_um = 2 * radius * a.cell_radius_um / cell_radius
    print(f"tube: R = {radius}, length {length}, window |x - {xc}| <= {half:.4f} "
          f"(L_w = {period:.4f}); D = {d_um:.2f} um; centreline speed {u_centre}, "
          f"mean {u_mean}; {len(frames)} frames to t = {times[-1]:g}")
    mu_rows = relative_viscosity(a.out)
    print("| t | cells in window | H_T | <U_c>/u_mean | H_T/H_D | H_D | Pries H_T/H_D at that H_D "
          "| cell-free layer | mu_app/mu | Pries mu_rel at that H_D |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    plotted, hds = [], []
    for b in range(1, len(rows), a.every_rows):
        block = rows[b:b + a.every_rows]
        n = np.mean([r[1] for r in block])
        ht = n * v_cell / v_window
        sp = np.nanmean([r[2] for r in block])
        ratio = u_mean / sp
        hd = ht / ratio
        layer = radius - np.nanmean([r[3] for r in block])
        # The steps after the block's first frame up to its last.
        sel = (mu_rows[:, 0] > rows[b - 1][0]) & (mu_rows[:, 0] <= block[-1][0] + 1e-12)
        mu = f"{mu_rows[sel, 1].mean():.4f}" if sel.any() else "-"
        pries_mu = f"{pries_mu_rel(d_um, hd):.3f}" if 0 < hd < 1 else "-"
        if 0 < hd < 1:
            plotted.append((0.5 * (block[0][0] + block[-1][0]), ratio))
            hds.append(hd)
        print(f"| {block[0][0]:g}–{block[-1][0]:g} | {n:.2f} | {ht:.3f} | {sp / u_mean:.3f} | "
              f"{ratio:.3f} | {hd:.3f} | {pries_ht_over_hd(d_um, hd):.3f} | {layer:.3f} | "
              f"{mu} | {pries_mu} |")
    t_half = 0.5 * times[-1]
    late = [c for c in crossings if c[0] >= t_half]
    ratios = [p[1] for p in plotted if p[0] >= t_half]
    if late and ratios:
        span = sum(c[1] - c[0] for c in late)
        n_late = np.mean([r[1] for r in rows if r[0] > t_half])
        hd_flux = sum(c[2] for c in late) * v_cell / span / (u_mean * math.pi * radius**2)
        print(f"\nflux check, t = {late[0][0]:g}–{late[-1][1]:g}: "
              f"{sum(c[2] for c in late):.1f} crossings a plane, H_D {hd_flux:.3f}, "
              f"H_T/H_D {n_late * v_cell / v_window / hd_flux:.3f} (table's rows there: "
              f"{np.mean(ratios):.3f})")
    if a.svg and hds:
        hd = float(np.mean(hds))
        svg(a.svg, mu_rows, plotted, pries_mu_rel(d_um, hd), pries_ht_over_hd(d_um, hd))
        print(f"plot: {a.svg} (Pries at the mean H_D {hd:.3f}: mu_rel "
              f"{pries_mu_rel(d_um, hd):.3f}, H_T/H_D {pries_ht_over_hd(d_um, hd):.3f})")


if __name__ == "__main__":
    main()
