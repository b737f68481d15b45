#!/usr/bin/env python3
"""Issue 53 item 8: project the FMM's strong and weak efficiency past one node with a LogGP-type
model fed by per-rank logs of `mpirun -n K mobo fmm` at K = 1-16 (oversubscribed is fine: the
counts do not depend on timing).

    cargo build --release --features mpi
    python3 benches/loggp_projection.py [--ranks 1,2,4,8,16] [--per-rank 20000] \\
        [--svg docs/scaling_projection.svg]

Per rank and evaluation the runs give: the points it owns, the bytes and messages it sends, the
top-of-tree bytes it receives, and the share of its far-field work that other ranks repeat. The
one-rank run gives the work per point `w` (seconds, this machine, one thread). The model of one
evaluation on rank count K with P points per rank:

    T(K, P) = w P (1 + r(K)) + m(K) (L + 2o) + B(K, P) G

with `m` the messages and `B` the bytes the busiest rank sends, and the network parameters of an
inter-node fabric (defaults: L = 1.5 us, o = 0.5 us, G = 1/(3 GB/s) per rank: a 100 Gb/s
InfiniBand port shared by four ranks; give --latency, --overhead, --gap-gbs). How the logs are
carried past K = 16 is the model's content; each choice is printed:

* the locally essential tree (LET + routing bytes): a surface law. In weak scaling a rank's
  boundary does not grow once it is interior, so the K = 16 value (the largest measured) is
  kept; in strong scaling it scales as P^(2/3) from it;
* the top of the tree as built: a top box of level l is shared by about K/8^l + 2 ranks, and
  its owner receives one partial from each, so the busiest owner receives ~ K/64 partials of
  level 2 (linear in K). Fitted as a + b K to the measured top bytes at K = 4..16. The remedy
  (a reduction over the sharers in log K stages, PVFMM's hypercube, not built) is projected
  beside it as a + b' log2 K;
* messages: fitted as a + b log2 K (neighbours plus top partners);
* repeated far work: its K = 16 value.

Efficiency: weak E(K) = T(1, P) / T(K, P); strong E(K) = T(1, N) / (K T(K, N/K)) with N =
--strong-points (default 10^8). These are the network's share only: the model has no memory
bandwidth, no imbalance beyond the repeated work, no waiting; multiply by the efficiency
measured inside one node (benches/RESULTS.md) for a whole-machine figure. MOBO (Rahimian et al., SC'10) reported 0.75 weak at
196,608 cores.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fmm_vs_fmm3d import cloud  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOBO = os.environ.get("MOBO", os.path.join(ROOT, "target", "release", "mobo"))
MPIRUN = os.environ.get("MPIRUN", "mpirun")


def run(k, per_rank, kernel, digits, tmp):
    n = per_rank * k
    rng = np.random.default_rng(5)
    src = cloud("spheres", n, rng)
    dens = rng.standard_normal((n, 3) if kernel == "stokeslet" else n)
    sp, dp = os.path.join(tmp, "s.npy"), os.path.join(tmp, "d.npy")
    np.save(sp, src)
    np.save(dp, dens)
    env = dict(os.environ, RAYON_NUM_THREADS="1", OMP_NUM_THREADS="1")
    cmd = [MOBO, "fmm", "--kernel", kernel, "--sources", sp, "--density", dp,
           "--digits", str(digits), "--out", os.path.join(tmp, "u.npy"), "--repeat", "2"]
    if k > 1:
        cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "--bind-to", "none",
               "-n", str(k)] + cmd
    o = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if o.returncode != 0:
        sys.exit(f"{' '.join(cmd)}\n{o.stderr}")
    return json.loads(o.stdout.strip().splitlines()[-1])


def fit(xs, ys, basis):
    """Least squares y = a + b basis(x)."""
    a = np.array([[1.0, basis(x)] for x in xs])
    coef, *_ = np.linalg.lstsq(a, np.array(ys, float), rcond=None)
    return coef


def svg(path, ks, series, mobo):
    """A log-x line plot of efficiency against ranks, as SVG text."""
    w, h, l, r, t, b = 640, 400, 60, 20, 20, 50
    x0, x1 = math.log10(ks[0]), math.log10(ks[-1])
    px = lambda k: l + (math.log10(k) - x0) / (x1 - x0) * (w - l - r)
    py = lambda e: t + (1.0 - e) * (h - t - b)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" '
           f'font-family="sans-serif" font-size="12">',
           f'<rect width="{w}" height="{h}" fill="white"/>']
    for e in [0, 0.25, 0.5, 0.75, 1.0]:
        out.append(f'<line x1="{l}" y1="{py(e)}" x2="{w - r}" y2="{py(e)}" stroke="#ddd"/>')
        out.append(f'<text x="{l - 8}" y="{py(e) + 4}" text-anchor="end">{e:.2f}</text>')
    for d in range(int(math.ceil(x0)), int(x1) + 1):
        out.append(f'<line x1="{px(10 ** d)}" y1="{t}" x2="{px(10 ** d)}" y2="{h - b}" '
                   'stroke="#ddd"/>')
        out.append(f'<text x="{px(10 ** d)}" y="{h - b + 16}" text-anchor="middle">10^{d}</text>')
    out.append(f'<text x="{(l + w - r) / 2}" y="{h - 10}" text-anchor="middle">ranks K</text>')
    out.append(f'<text x="14" y="{(t + h - b) / 2}" transform="rotate(-90 14 {(t + h - b) / 2})" '
               'text-anchor="middle">efficiency</text>')
    for i, (name, colour, dash, es) in enumerate(series):
        pts = " ".join(f"{px(k):.1f},{py(max(e, 0.0)):.1f}" for k, e in zip(ks, es))
        out.append(f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="2" '
                   f'stroke-dasharray="{dash}"/>')
        out.append(f'<text x="{l + 10}" y="{t + 16 + 16 * i}" fill="{colour}">{name}</text>')
    k, e = mobo
    out.append(f'<circle cx="{px(k)}" cy="{py(e)}" r="5" fill="black"/>')
    out.append(f'<text x="{px(k) - 8}" y="{py(e) - 8}" text-anchor="end">MOBO (SC\'10), '
               f'weak {e} at {k}</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ranks", default="1,2,4,8,16")
    ap.add_argument("--per-rank", type=int, default=20000)
    ap.add_argument("--kernel", default="stokeslet")
    ap.add_argument("--digits", type=int, default=6)
    ap.add_argument("--latency", type=float, default=1.5e-6)
    ap.add_argument("--overhead", type=float, default=0.5e-6)
    ap.add_argument("--gap-gbs", type=float, default=3.0)
    ap.add_argument("--strong-points", type=float, default=1e8)
    ap.add_argument("--svg", default=None)
    a = ap.parse_args()
    ks = [int(x) for x in a.ranks.split(",")]
    assert ks[0] == 1, "the first K must be 1 (the work per point)"
    logs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k in ks:
            logs[k] = run(k, a.per_rank, a.kernel, a.digits, tmp)
    one = logs[1]
    w = one["eval_s"] / a.per_rank
    print(f"work per point (one rank, one thread): {w * 1e6:.2f} us "
          f"({one['eval_s']:.3f} s for {a.per_rank} points)")
    print("\n| K | points/rank (max) | max MB sent | LET + routing MB | top MB received | "
          "messages (max) | repeated far work |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for k in ks[1:]:
        i = logs[k]
        row = dict(k=k, pts=max(i["rank_sources"]), sent=max(i["rank_bytes_sent"]),
                   let=max(i["rank_let_bytes_sent"]), top=max(i["rank_top_bytes_received"]),
                   msgs=max(i["rank_messages_sent"]),
                   rep=max(i["rank_repeated_far_fraction"]))
        rows.append(row)
        print(f"| {k} | {row['pts']} | {row['sent'] / 1e6:.2f} | {row['let'] / 1e6:.2f} | "
              f"{row['top'] / 1e6:.3f} | {row['msgs']} | {100 * row['rep']:.1f} % |")
    last = rows[-1]
    fit_k = [r["k"] for r in rows if r["k"] >= 4]
    top_lin = fit(fit_k, [r["top"] for r in rows if r["k"] >= 4], lambda x: x)
    top_log = fit(fit_k, [r["top"] for r in rows if r["k"] >= 4], lambda x: math.log2(x))
    msg_log = fit([r["k"] for r in rows], [r["msgs"] for r in rows], lambda x: math.log2(x))
    print(f"\nfits: top bytes = {top_lin[0]:.3g} + {top_lin[1]:.3g} K (as built), "
          f"= {top_log[0]:.3g} + {top_log[1]:.3g} log2 K (with a log K reduction, not built); "
          f"messages = {msg_log[0]:.3g} + {msg_log[1]:.3g} log2 K; LET + routing kept at "
          f"{last['let'] / 1e6:.2f} MB (weak), scaled as P^(2/3) (strong)")
    lo, g = a.latency + 2 * a.overhead, 1.0 / (a.gap_gbs * 1e9)
    print(f"network: L + 2o = {lo * 1e6:.1f} us a message, G = {g * 1e9:.3f} ns a byte "
          f"({a.gap_gbs} GB/s per rank)")

    def t_eval(k, p, top_model):
        if k == 1:
            return w * p
        rep = last["rep"]
        let = last["let"] * (p / a.per_rank) ** (2.0 / 3.0)
        top = max(top_model[0] + top_model[1] * (k if top_model is top_lin else math.log2(k)),
                  0.0)
        msgs = msg_log[0] + msg_log[1] * math.log2(k)
        return w * p * (1 + rep) + msgs * lo + (let + top) * g

    n_strong = a.strong_points
    proj = [16, 64, 256, 1024, 4096, 16384, 65536, 196608]
    print(f"\nProjection (P = {a.per_rank} points per rank weak; N = {n_strong} points strong):\n")
    print("| K | weak, top as built | weak, log K top | strong, top as built | "
          "strong, log K top | strong points/rank |")
    print("|---|---|---|---|---|---|")
    series = {n: [] for n in ["wb", "wl", "sb", "sl"]}
    for k in proj:
        wb = t_eval(1, a.per_rank, top_lin) / t_eval(k, a.per_rank, top_lin)
        wl = t_eval(1, a.per_rank, top_log) / t_eval(k, a.per_rank, top_log)
        p = n_strong / k
        sb = t_eval(1, n_strong, top_lin) / (k * t_eval(k, p, top_lin))
        sl = t_eval(1, n_strong, top_log) / (k * t_eval(k, p, top_log))
        for n, v in zip(series, [wb, wl, sb, sl]):
            series[n].append(v)
        print(f"| {k} | {wb:.2f} | {wl:.2f} | {sb:.3f} | {sl:.3f} | {p:.0f} |")
    if a.svg:
        svg(a.svg, proj, [
            ("weak, top as built", "#b2182b", "", series["wb"]),
            ("weak, top reduced in log K stages (not built)", "#2166ac", "", series["wl"]),
            ("strong, top as built", "#b2182b", "6,4", series["sb"]),
            ("strong, top reduced in log K stages", "#2166ac", "6,4", series["sl"]),
        ], (196608, 0.75))
        print(f"\n{a.svg} written")


if __name__ == "__main__":
    main()
