#!/usr/bin/env python3
"""mobo fmm against FMM3D (pip install fmm3dpy) on the same clouds, same requested accuracy,
2 threads each; both checked against direct sums at sampled targets.

    cargo build --release && python3 benches/fmm_vs_fmm3d.py [--sizes 10000,100000,1000000]

Prints a Markdown table (times in seconds; "mobo total" is setup + one evaluation as the JSON
line reports them, "mobo eval" is one evaluation, which an iterative solver repeats; "mobo
one-shot" is the wall time of a whole `mobo fmm` process (start, reading and writing the .npy
files, tree, operators with the fits from a warm operator cache, one evaluation), the way a
script calls it: each case runs once to warm the cache (its own `MOBO_OPERATOR_CACHE` unless
set), then again for the timings. FMM3D has no separate setup; its time is the call's.
"""
import argparse, json, os, subprocess, sys, tempfile, time
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOBO = os.path.join(ROOT, "target", "release", "mobo")


def cloud(kind, n, rng):
    if kind == "uniform":
        return rng.random((n, 3))
    # points on ~300 small spheres (cell-like), radius 0.03
    per = max(n // 300, 20)
    m = -(-n // per)
    c = rng.random((m, 3))
    v = rng.standard_normal((m * per, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    return (np.repeat(c, per, axis=0) + 0.03 * v)[:n]


def direct(kind, src, dens, tgt):
    out = np.zeros((len(tgt), 3 if kind == "stokeslet" else 1))
    for i, x in enumerate(tgt):
        r = x - src
        d2 = np.einsum("ij,ij->i", r, r)
        inv = np.where(d2 > 0, 1 / np.sqrt(np.where(d2 > 0, d2, 1)), 0)
        if kind == "laplace":
            out[i, 0] = np.dot(dens, inv) / (4 * np.pi)
        else:
            rf = np.einsum("ij,ij->i", r, dens) * inv**3
            out[i] = (dens.T @ inv + r.T @ rf) / (8 * np.pi)
    return out


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def run_mobo(kind, src, dens, digits, tmp):
    np.save(os.path.join(tmp, "s.npy"), src)
    np.save(os.path.join(tmp, "q.npy"), dens)
    t = time.time()
    o = subprocess.run([MOBO, "fmm", "--kernel", kind, "--sources", os.path.join(tmp, "s.npy"),
                        "--density", os.path.join(tmp, "q.npy"), "--digits", str(digits),
                        "--out", os.path.join(tmp, "u.npy")], capture_output=True, text=True)
    wall = time.time() - t
    if o.returncode != 0:
        sys.exit(o.stderr)
    info = json.loads(o.stdout)
    u = np.load(os.path.join(tmp, "u.npy"))
    return u.reshape(len(src), -1), info, wall


def run_fmm3d(kind, src, dens, digits):
    import fmm3dpy
    eps = 10.0 ** -digits
    t = time.time()
    if kind == "laplace":
        out = fmm3dpy.lfmm3d(eps=eps, sources=src.T.copy(), charges=dens, pg=1)
        u = np.asarray(out.pot).reshape(-1, 1)  # FMM3D carries 1/(4 pi)
    else:
        out = fmm3dpy.stfmm3d(eps=eps, sources=src.T.copy(), stoklet=dens.T.copy(), ifppreg=1)
        u = np.asarray(out.pot).reshape(3, -1).T.copy()  # and 1/(8 pi)
    return u, time.time() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--digits", default="3,6")
    ap.add_argument("--kernels", default="laplace,stokeslet")
    ap.add_argument("--clouds", default="uniform,spheres")
    ap.add_argument("--samples", type=int, default=100)
    a = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    os.environ.setdefault("RAYON_NUM_THREADS", "2")
    os.environ.setdefault("MOBO_OPERATOR_CACHE", os.path.join(ROOT, "target", "operator-cache"))
    print("| kernel | cloud | N | digits | order | mobo err | mobo eval s | mobo total s | mobo one-shot s | FMM3D err | FMM3D s | FMM3D/mobo eval | FMM3D/mobo total | FMM3D/mobo one-shot |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(1)
    with tempfile.TemporaryDirectory() as tmp:
        for kind in a.kernels.split(","):
            for ck in a.clouds.split(","):
                for n in map(int, a.sizes.split(",")):
                    src = cloud(ck, n, rng)
                    dens = rng.uniform(-1, 1, n if kind == "laplace" else (n, 3))
                    idx = np.linspace(0, n - 1, a.samples).astype(int)
                    ref = direct(kind, src, dens, src[idx])
                    for d in map(int, a.digits.split(",")):
                        run_mobo(kind, src, dens, d, tmp)  # warms the operator cache
                        um, info, wall = run_mobo(kind, src, dens, d, tmp)
                        uf, tf = run_fmm3d(kind, src, dens, d)
                        em, ef = rel(um[idx], ref), rel(uf[idx], ref)
                        tot = info["setup_s"] + info["eval_s"]
                        print(f"| {kind} | {ck} | {n} | {d} | {info['order']} | {em:.1e} | {info['eval_s']:.3f} | {tot:.3f} | {wall:.3f} | {ef:.1e} | {tf:.3f} | {tf / info['eval_s']:.1f} | {tf / tot:.1f} | {tf / wall:.1f} |", flush=True)


if __name__ == "__main__":
    main()
