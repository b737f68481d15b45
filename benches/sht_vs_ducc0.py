#!/usr/bin/env python3
"""Compare mobo's batched spherical-harmonic transforms with ducc0's.

What it measures
----------------
For each (order p, number of surfaces N, threads T) it times

* mobo:  ``mobo bench-sht --order p --surfaces N --threads T --reps R``, which
  transforms ``3*N`` real scalar functions of degree <= p in one batched call
  (forward = grid -> coefficients, inverse = coefficients -> grid) on mobo's
  grid of p+1 Gauss-Legendre latitudes x 2p equispaced longitudes, and reports
  best-of-R wall times;
* ducc0: ``ducc0.sht.experimental.analysis_2d`` / ``synthesis_2d`` on a
  Gauss-Legendre grid (``geometry="GL"``) with lmax = mmax = p, p+1 rings and
  2p+2 longitudes (ducc0 needs nphi >= 2*mmax+1 for exact analysis), applied
  to the same number (3*N) of real functions, best-of-R wall time measured with
  ``time.perf_counter``.  ducc0's spin-0 transforms accept exactly one map per
  call, so the batch is a Python loop over the functions; all input and output
  arrays are allocated before the clock starts (outputs are written in place
  through the ``map=`` / ``alm=`` arguments).  With T > 1 two ways of using the
  threads are timed and the faster is reported: (a) ``nthreads=T`` inside each
  call, (b) the batch split over T Python threads, each calling ducc0 with
  ``nthreads=1`` (ducc0 releases the GIL during the transform).

The last column is (ducc0 analysis + synthesis) / (mobo forward + inverse);
a ratio > 1 means mobo is faster.

Before timing, a round trip (synthesis then analysis of random coefficients)
checks that the ducc0 set-up is an exact transform (error ~1e-13).

How to run
----------
    pip install numpy ducc0
    python3 benches/sht_vs_ducc0.py                 # full run, a few minutes
    python3 benches/sht_vs_ducc0.py --quick         # p in {6,16}, N in {100,1000}
    python3 benches/sht_vs_ducc0.py --mobo /path/to/mobo --threads 1

The mobo binary must already be built (``cargo build --release``); this
script does not build it.
"""

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

try:
    import ducc0
except ImportError:  # pragma: no cover - depends on the environment
    sys.exit("ducc0 is not installed: pip install ducc0")

REPO_ROOT = Path(__file__).resolve().parent.parent
SHT = ducc0.sht.experimental

# (p, surfaces) pairs.  p = 32 uses 3000 surfaces instead of 10000 for time.
FULL_CASES = [(6, 100), (6, 10000), (12, 100), (12, 10000),
              (16, 100), (16, 10000), (32, 100), (32, 3000)]
QUICK_CASES = [(6, 100), (6, 1000), (16, 100), (16, 1000)]


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------
def n_alm(p):
    """Number of complex coefficients in ducc0's (healpy) layout, lmax=mmax=p."""
    return (p + 1) * (p + 2) // 2


def ducc0_nphi(p):
    """Longitudes given to ducc0: the smallest even count >= 2p+1."""
    return 2 * p + 2


def random_real_alm(rng, count, p):
    """Random coefficients of `count` real functions (m=0 entries are real)."""
    alm = rng.standard_normal((count, n_alm(p))) \
        + 1j * rng.standard_normal((count, n_alm(p)))
    alm[:, :p + 1] = alm[:, :p + 1].real  # m = 0 block comes first
    return alm


def default_reps(surfaces):
    """Best-of-R: 3 repetitions for big batches, more for small (noisy) ones."""
    return 3 if surfaces >= 1000 else 10


def machine_info():
    """(CPU model name, logical CPU count) from lscpu, with fallbacks."""
    model, cpus = platform.processor() or "unknown", os.cpu_count()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True,
                             check=True).stdout
        for line in out.splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "Model name":
                model = value.strip()
            elif key.strip() == "CPU(s)":
                cpus = int(value.strip())
    except (OSError, subprocess.CalledProcessError, ValueError):
        pass
    return model, cpus


# --------------------------------------------------------------------------
# ducc0
# --------------------------------------------------------------------------
def ducc0_roundtrip_error(p, nphi, count=4, seed=1):
    """Max |alm - analysis(synthesis(alm))| over `count` random functions."""
    rng = np.random.default_rng(seed)
    alm = random_real_alm(rng, count, p)
    err = 0.0
    for a in alm:
        m = SHT.synthesis_2d(alm=a[None, :], lmax=p, spin=0, geometry="GL",
                             ntheta=p + 1, nphi=nphi, nthreads=1)
        back = SHT.analysis_2d(map=m, lmax=p, spin=0, geometry="GL",
                               nthreads=1)
        err = max(err, float(np.max(np.abs(back[0] - a))))
    return err


def ducc0_per_call_floor(reps=2000):
    """Time of one lmax=0 synthesis_2d call: Python/pybind/plan overhead."""
    a = np.zeros((1, 1), complex)
    m = np.zeros((1, 1, 2))
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(reps):
            SHT.synthesis_2d(alm=a, map=m, lmax=0, spin=0, geometry="GL",
                             nthreads=1)
        best = min(best, (time.perf_counter() - t0) / reps)
    return best


class Ducc0Batch:
    """Preallocated inputs/outputs for `count` functions of order p."""

    def __init__(self, p, count, seed=0):
        self.p = p
        rng = np.random.default_rng(seed)
        self.alm = random_real_alm(rng, count, p)
        self.alm_out = np.zeros_like(self.alm)
        self.maps = np.zeros((count, 1, p + 1, ducc0_nphi(p)))
        # Views are built here so that slicing is not timed.
        self.alm_in_views = [self.alm[i:i + 1] for i in range(count)]
        self.alm_out_views = [self.alm_out[i:i + 1] for i in range(count)]
        self.map_views = [self.maps[i] for i in range(count)]

    def synthesis(self, lo, hi, nthreads):
        p = self.p
        for a, m in zip(self.alm_in_views[lo:hi], self.map_views[lo:hi]):
            SHT.synthesis_2d(alm=a, map=m, lmax=p, spin=0, geometry="GL",
                             nthreads=nthreads)

    def analysis(self, lo, hi, nthreads):
        p = self.p
        for m, a in zip(self.map_views[lo:hi], self.alm_out_views[lo:hi]):
            SHT.analysis_2d(map=m, alm=a, lmax=p, spin=0, geometry="GL",
                            nthreads=nthreads)


def best_of(reps, fn):
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def time_ducc0(p, functions, threads, reps):
    """Best-of-reps (analysis_s, synthesis_s, how) for `functions` maps."""
    batch = Ducc0Batch(p, functions)
    n = functions

    # Warm-up (also fills the maps that analysis then reads: band-limited data).
    batch.synthesis(0, n, 1)
    batch.analysis(0, min(n, 8), 1)

    # (a) ducc0's own threading inside every call.
    syn = best_of(reps, lambda: batch.synthesis(0, n, threads))
    ana = best_of(reps, lambda: batch.analysis(0, n, threads))
    how = "1 thread" if threads == 1 else f"nthreads={threads} per call"
    if threads == 1:
        return ana, syn, how

    # (b) split the batch over Python threads, nthreads=1 per call.
    bounds = [(k * n // threads, (k + 1) * n // threads)
              for k in range(threads)]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        def split(method):
            futures = [pool.submit(method, lo, hi, 1) for lo, hi in bounds]
            for f in futures:
                f.result()
        split(batch.synthesis)  # start the worker threads
        syn_b = best_of(reps, lambda: split(batch.synthesis))
        ana_b = best_of(reps, lambda: split(batch.analysis))
    if syn_b + ana_b < syn + ana:
        return ana_b, syn_b, f"{threads} Python threads x nthreads=1"
    return ana, syn, how


# --------------------------------------------------------------------------
# mobo
# --------------------------------------------------------------------------
def time_mobo(mobo, p, surfaces, threads, reps):
    cmd = [str(mobo), "bench-sht", "--order", str(p), "--surfaces",
           str(surfaces), "--threads", str(threads), "--reps", str(reps)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    lines = [ln for ln in out.stdout.splitlines() if ln.strip().startswith("{")]
    if not lines:
        raise RuntimeError(f"no JSON from {' '.join(cmd)}:\n{out.stdout}")
    rec = json.loads(lines[-1])
    if rec.get("p") != p or rec.get("functions") != 3 * surfaces:
        raise RuntimeError(f"unexpected mobo output: {rec}")
    return rec


# --------------------------------------------------------------------------
def parse_args():
    ap = argparse.ArgumentParser(
        description="Time mobo bench-sht against ducc0 SHTs on the same sizes.")
    ap.add_argument("--mobo", type=Path,
                    default=REPO_ROOT / "target" / "release" / "mobo",
                    help="mobo binary (default: <repo>/target/release/mobo)")
    ap.add_argument("--quick", action="store_true",
                    help="only p in {6,16} with 100 and 1000 surfaces")
    ap.add_argument("--threads", default="1,2",
                    help="comma-separated thread counts (default: 1,2)")
    ap.add_argument("--reps", type=int, default=None,
                    help="best-of-R repetitions (default: 3 for >=1000 "
                         "surfaces, 10 otherwise)")
    return ap.parse_args()


def main():
    args = parse_args()
    if not args.mobo.is_file():
        sys.exit(f"mobo binary not found: {args.mobo} (build it, or --mobo)")
    threads_list = [int(t) for t in args.threads.split(",") if t.strip()]
    cases = QUICK_CASES if args.quick else FULL_CASES
    orders = sorted({p for p, _ in cases})

    model, cpus = machine_info()
    now = datetime.datetime.now().isoformat(timespec="seconds")
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"# mobo vs ducc0 SHT — {now} — CPU: {model}, {cpus} logical CPUs "
          f"— ducc0 {ducc0.__version__}, numpy {np.__version__}, "
          f"Python {platform.python_version()} — load average at start: {load}")
    print()

    # Sanity: ducc0 round trip is exact with nphi = 2p+2 (and not with 2p).
    print("ducc0 round-trip check (synthesis -> analysis, random real alm):")
    for p in orders:
        err = ducc0_roundtrip_error(p, ducc0_nphi(p))
        err_2p = ducc0_roundtrip_error(p, 2 * p)
        status = "ok" if err < 1e-10 else "FAILED"
        print(f"  p={p:2d}: max |error| = {err:.1e} with nphi=2p+2 ({status}); "
              f"{err_2p:.1e} with nphi=2p")
        if err >= 1e-10:
            sys.exit("ducc0 round trip is not exact; timings would be meaningless")
    floor = ducc0_per_call_floor()
    print(f"ducc0 per-call floor (lmax=0 synthesis_2d, nthreads=1): "
          f"{floor * 1e6:.1f} us")
    print()

    header = ("| p | surfaces | threads | mobo fwd (ms) | mobo inv (ms) "
              "| ducc0 analysis (ms) | ducc0 synthesis (ms) "
              "| ratio fwd+inv (ducc0 time / mobo time) | ducc0 threading |")
    print(header)
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    t_start = time.perf_counter()
    for p, surfaces in cases:
        for threads in threads_list:
            reps = args.reps or default_reps(surfaces)
            rec = time_mobo(args.mobo, p, surfaces, threads, reps)
            ana, syn, how = time_ducc0(p, rec["functions"], threads, reps)
            mobo_total = rec["forward_s"] + rec["inverse_s"]
            ratio = (ana + syn) / mobo_total
            print(f"| {p} | {surfaces} | {threads} "
                  f"| {rec['forward_s'] * 1e3:.3f} | {rec['inverse_s'] * 1e3:.3f} "
                  f"| {ana * 1e3:.3f} | {syn * 1e3:.3f} | {ratio:.2f} | {how} |",
                  flush=True)
    elapsed = time.perf_counter() - t_start

    print()
    print("Notes:")
    print("- functions = 3 x surfaces real scalar functions, lmax = mmax = p, "
          "Gauss-Legendre latitudes (p+1 rings) for both libraries.")
    print("- mobo uses 2p longitudes; ducc0 gets 2p+2 (needed for exact "
          "analysis, nphi >= 2*mmax+1), i.e. (p+1)/p times as many points: "
          + ", ".join(f"+{100 / p:.0f}% at p={p}" for p in orders) + ".")
    print("- ducc0 coefficients use its standard complex (healpy) layout, "
          "(p+1)(p+2)/2 complex numbers per function.")
    print("- ducc0's spin-0 synthesis_2d/analysis_2d take one map per call, so "
          "its batch is a Python loop over functions (arrays preallocated, "
          "outputs written in place); the per-call floor above is part of "
          "every ducc0 call.")
    print("- threads > 1: the faster of ducc0 nthreads=T per call and the batch "
          "split over T Python threads with nthreads=1 is reported "
          "(last column).")
    print("- all times are best of R runs (R = 3 for >= 1000 surfaces, else 10"
          + (f"; overridden: R = {args.reps}" if args.reps else "")
          + "); ratio > 1 means mobo is faster.")
    print(f"- timing loop took {elapsed:.0f} s.")


if __name__ == "__main__":
    main()
