#!/usr/bin/env python3
"""`mpirun -n K mobo fmm`: time per evaluation by phase, bytes sent per rank and load imbalance
for K ranks of one thread each, strong (fixed N) and weak (fixed N per rank) scaling:

    cargo build --release --features mpi
    python3 benches/fmm_scaling_mpi.py [--ranks 1,2] [--strong 1000000] [--weak 200000] \\
        [--kernels laplace,stokeslet] [--clouds uniform,spheres] [--digits 6]

Needs numpy and mpirun (Debian's openmpi-bin). Prints Markdown tables. Every time is the
maximum over ranks (the evaluation ends when the slowest rank does); "comm" is the time in
point-to-point exchanges of the evaluation; bytes are what each rank sent during one
evaluation (max and mean over ranks); imbalance is max/mean of the ranks' evaluation times.
Efficiency: strong T(1)/(K·T(K)), weak T(1)/T(K), with T(1) one rank of one thread.

On another machine (the 16-core one), point MOBO at the carried binary and MPIRUN at the
carried mpirun.
"""
import argparse, json, os, subprocess, sys, tempfile
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fmm_vs_fmm3d import cloud  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOBO = os.environ.get("MOBO", os.path.join(ROOT, "target", "release", "mobo"))
MPIRUN = os.environ.get("MPIRUN", "mpirun")


def run(kind, k, src_path, dens_path, digits, tmp):
    env = dict(os.environ, RAYON_NUM_THREADS="1", OMP_NUM_THREADS="1")
    cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "--bind-to", "none", "-n", str(k),
           MOBO, "fmm", "--kernel", kind, "--sources", src_path, "--density", dens_path,
           "--digits", str(digits), "--out", os.path.join(tmp, "u.npy")]
    o = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if o.returncode != 0:
        sys.exit(f"{' '.join(cmd)}\n{o.stderr}")
    return json.loads(o.stdout.strip().splitlines()[-1])


def row(kind, ck, n, k, info, base, weak):
    ph = info["phases_max_s"]
    up = ph["p2m"] + ph["m2m"]
    m2l = ph["m2l_fft"] + ph["m2l_hadamard"]
    down = ph["p2l"] + ph["l2l"] + ph["l2p"] + ph["m2p"]
    b = info["rank_bytes_sent"]
    ev = info["eval_s"]
    eff = base / ev if weak else base / (k * ev)
    pts = info["rank_sources"]
    return (f"| {kind} | {ck} | {n} | {k} | {min(pts)}–{max(pts)} | {info['order']} | "
            f"{info['setup_s']:.2f} | {ev:.3f} | {up:.3f} | {m2l:.3f} | {down:.3f} | "
            f"{ph['p2p']:.3f} | {max(info['rank_comm_s']):.4f} | {max(b) / 1e6:.2f} / "
            f"{sum(b) / len(b) / 1e6:.2f} | {info['load_imbalance']:.2f} | {100 * eff:.0f} % |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ranks", default="1,2")
    ap.add_argument("--strong", type=int, default=1000000, help="points (0: skip)")
    ap.add_argument("--weak", type=int, default=200000, help="points per rank (0: skip)")
    ap.add_argument("--kernels", default="laplace,stokeslet")
    ap.add_argument("--clouds", default="uniform,spheres")
    ap.add_argument("--digits", type=int, default=6)
    a = ap.parse_args()
    ranks = [int(k) for k in a.ranks.split(",")]
    head = ("| kernel | cloud | N | K | points/rank | order | setup s | eval s | P2M+M2M | M2L | "
            "L2L+L2P+M2P | P2P | comm s | MB sent/rank max / mean | imbalance | efficiency |")
    rng = np.random.default_rng(5)
    with tempfile.TemporaryDirectory() as tmp:
        for mode, size in (("strong", a.strong), ("weak", a.weak)):
            if size <= 0:
                continue
            print(f"\n{mode} scaling ({'N = ' if mode == 'strong' else 'N/K = '}{size}, "
                  f"{a.digits} digits, one thread per rank)\n")
            print(head)
            print("|---" * (head.count("|") - 1) + "|")
            for kind in a.kernels.split(","):
                for ck in a.clouds.split(","):
                    base = None
                    for k in ranks:
                        n = size if mode == "strong" else size * k
                        src = cloud(ck, n, rng)
                        dens = rng.uniform(-1, 1, n if kind == "laplace" else (n, 3))
                        sp, dp = os.path.join(tmp, "s.npy"), os.path.join(tmp, "q.npy")
                        np.save(sp, src)
                        np.save(dp, dens)
                        info = run(kind, k, sp, dp, a.digits, tmp)
                        if base is None:
                            base = info["eval_s"] if k == 1 else float("nan")
                        print(row(kind, ck, n, k, info, base, mode == "weak"), flush=True)


if __name__ == "__main__":
    main()
