#!/usr/bin/env python3
"""Bytes each rank of `mpirun -n K mobo fmm` sends and receives in one evaluation, in weak
scaling (a fixed number of points per rank): the counts of issue 53's item 2 (the LET's
surface law, the top of the tree's log K). They do not depend on timing, so they are checkable
on a 2-core machine with `--oversubscribe`:

    cargo build --release --features mpi
    python3 benches/let_bytes.py [--ranks 4,16] [--per-rank 40000] [--kernel stokeslet] \\
        [--cloud spheres] [--digits 6]

Prints one Markdown row per K: max over ranks of the bytes sent (all of the evaluation: routing,
LET, top), of the LET + routing part, of the top-of-tree bytes received, and their ratios to
the first K, the largest share of a rank's far-field work (M2L pairs and P2L sources) spent on
top boxes that other ranks compute too, the most bytes a rank sent while building the tree
(splitters, routing of the points, LET structure), the points' balance over ranks, the most
messages a rank sent in the evaluation, and the most bytes of top-box expansions a rank sent
(partials and whole expansions: what the owner of a widely used box pays).
"""
import argparse, json, os, subprocess, sys, tempfile
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fmm_vs_fmm3d import cloud  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOBO = os.environ.get("MOBO", os.path.join(ROOT, "target", "release", "mobo"))
MPIRUN = os.environ.get("MPIRUN", "mpirun")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ranks", default="4,16")
    ap.add_argument("--per-rank", type=int, default=40000)
    ap.add_argument("--kernel", default="stokeslet")
    ap.add_argument("--cloud", default="spheres")
    ap.add_argument("--digits", type=int, default=6)
    a = ap.parse_args()
    print("| K | N | max MB sent | max LET + routing MB | max top MB received | "
          "ratio sent | ratio LET | ratio top | max repeated far work | max setup MB sent | "
          "points max/mean | max messages sent | max top MB sent |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    base = None
    with tempfile.TemporaryDirectory() as tmp:
        for k in [int(x) for x in a.ranks.split(",")]:
            n = a.per_rank * k
            rng = np.random.default_rng(5)
            src = cloud(a.cloud, n, rng)
            dens = rng.standard_normal((n, 3) if a.kernel == "stokeslet" else n)
            sp, dp = os.path.join(tmp, "s.npy"), os.path.join(tmp, "d.npy")
            np.save(sp, src)
            np.save(dp, dens)
            env = dict(os.environ, RAYON_NUM_THREADS="1", OMP_NUM_THREADS="1")
            cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "--bind-to", "none",
                   "-n", str(k), MOBO, "fmm", "--kernel", a.kernel, "--sources", sp,
                   "--density", dp, "--digits", str(a.digits),
                   "--out", os.path.join(tmp, "u.npy")]
            o = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if o.returncode != 0:
                sys.exit(f"{' '.join(cmd)}\n{o.stderr}")
            info = json.loads(o.stdout.strip().splitlines()[-1])
            row = [max(info["rank_bytes_sent"]), max(info["rank_let_bytes_sent"]),
                   max(info["rank_top_bytes_received"])]
            if base is None:
                base = row
            r = [x / b if b else float("nan") for x, b in zip(row, base)]
            print(f"| {k} | {n} | {row[0] / 1e6:.2f} | {row[1] / 1e6:.2f} | {row[2] / 1e6:.2f} | "
                  f"{r[0]:.2f} | {r[1]:.2f} | {r[2]:.2f} | "
                  f"{100 * max(info['rank_repeated_far_fraction']):.1f} % | "
                  f"{max(info.get('rank_setup_bytes_sent', [0])) / 1e6:.3f} | "
                  f"{balance(info):.3f} | {max(info['rank_messages_sent'])} | "
                  f"{top_sent(info) / 1e6:.3f} |", flush=True)


def top_sent(info):
    """Most bytes of top-box expansions a rank sent (all it sent less the LET and routing)."""
    return max(b - l for b, l in zip(info["rank_bytes_sent"], info["rank_let_bytes_sent"]))


def balance(info):
    """Largest rank's share of the points (sources and targets) over the mean."""
    load = [s + t for s, t in zip(info["rank_sources"], info["rank_targets"])]
    return max(load) / (sum(load) / len(load))


if __name__ == "__main__":
    main()
