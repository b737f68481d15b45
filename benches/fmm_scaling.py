#!/usr/bin/env python3
"""Time of `mobo fmm` against N (uniform cube and small-sphere clouds, 2 threads):

    cargo build --release && python3 benches/fmm_scaling.py [--digits 6] [--sizes ...]

Prints a Markdown table: setup (tree + operators in a fresh process), one evaluation, and the
evaluation time per point, which stays flat when the cost grows linearly with N.
"""
import argparse, os, sys, tempfile
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fmm_vs_fmm3d import cloud, run_mobo  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="10000,30000,100000,300000,1000000")
    ap.add_argument("--digits", type=int, default=6)
    ap.add_argument("--kernels", default="laplace,stokeslet")
    ap.add_argument("--clouds", default="uniform,spheres")
    a = ap.parse_args()
    os.environ.setdefault("RAYON_NUM_THREADS", "2")
    print("| kernel | cloud | N | order | depth | boxes | setup s | eval s | eval µs/point | points/s/core |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(3)
    with tempfile.TemporaryDirectory() as tmp:
        for kind in a.kernels.split(","):
            for ck in a.clouds.split(","):
                for n in map(int, a.sizes.split(",")):
                    src = cloud(ck, n, rng)
                    dens = rng.uniform(-1, 1, n if kind == "laplace" else (n, 3))
                    _, i, _ = run_mobo(kind, src, dens, a.digits, tmp)
                    ev = i["eval_s"]
                    print(f"| {kind} | {ck} | {n} | {i['order']} | {i['tree_depth']} | {i['boxes']} | {i['setup_s']:.2f} | {ev:.3f} | {1e6 * ev / n:.2f} | {n / ev / i['threads']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
