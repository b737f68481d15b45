#!/usr/bin/env bash
# Ranks × threads on the 16-core device machine (issue 53, items 1 and 7): `mpirun -n K mobo fmm`
# with T rayon threads per rank, K·T = 16, on 10⁶ Stokeslet points of the sphere cloud (strong),
# and on 2·10⁵ points per core (weak), against one rank of one thread in the same run. That
# machine has no cargo and no MPI: build here and carry the binary and Debian's OpenMPI:
#
#   cargo build --release --features mpi && mkdir -p .devbin && cp target/release/mobo .devbin/
#   (mkdir -p .mpi && cd .mpi && apt-get download ...)   # the list in scripts/carried_mpi.sh
#
# then there: `bash scripts/device_ranks_threads.sh` with .devbin and .mpi carried. Each run's
# JSON line goes to $OUT/fmm.jsonl; the table (benches/let_bytes.py's columns and times) to
# $OUT/ranks_threads.md. MPI is called from one thread of each rank (MPI_THREAD_FUNNELED);
# ranks are bound to cores in blocks of T (`--map-by slot:PE=T --bind-to core`), so a rank's
# threads share its cores' caches.
# STRONG_N, WEAK_PER and CORES (default 10⁶, 2·10⁵, 16) shrink it for a trial run elsewhere.
set -u
OUT=${OUT:-device-out}
STRONG_N=${STRONG_N:-1000000}
WEAK_PER=${WEAK_PER:-200000}
CORES=${CORES:-16}
export STRONG_N WEAK_PER CORES
mkdir -p "$OUT"
. scripts/carried_mpi.sh .mpi
chmod +x .devbin/mobo
export MOBO_OPERATOR_CACHE=/tmp/mobo-ops
{ nproc; lscpu | grep -E "Model name|Socket|NUMA node|L2|L3"; date -u; } > "$OUT/cpu.txt" 2>&1
python3 - <<'PY'
import numpy as np, sys
sys.path.insert(0, "benches")
from fmm_vs_fmm3d import cloud
import os
sn, wp, c = (int(os.environ[k]) for k in ("STRONG_N", "WEAK_PER", "CORES"))
for n in (wp, sn, wp * c):
    rng = np.random.default_rng(5)
    np.save(f"/tmp/s{n}.npy", cloud("spheres", n, rng))
    np.save(f"/tmp/d{n}.npy", rng.standard_normal((n, 3)))
PY
# Binding where the machine allows it (a sandbox may not): else every rank floats.
bind=core
"$MPIRUN" --allow-run-as-root --map-by slot:PE=8 --bind-to core -n 2 true > "$OUT/bind.txt" 2>&1 ||
    bind=none
echo "binding: $bind" | tee -a "$OUT/cpu.txt"
run() { # K T N
    local k=$1 t=$2 n=$3 how=(--bind-to none)
    [ "$bind" = core ] && how=(--map-by "slot:PE=$t" --bind-to core)
    RAYON_NUM_THREADS=$t OMP_NUM_THREADS=$t timeout 200 "$MPIRUN" --allow-run-as-root \
        --oversubscribe "${how[@]}" -n "$k" .devbin/mobo fmm \
        --kernel stokeslet --sources "/tmp/s$n.npy" --density "/tmp/d$n.npy" --digits 6 \
        --repeat 2 --out /tmp/u.npy | tail -n 1 | python3 -c "
import json, sys
d = json.loads(sys.stdin.read()); d['threads_per_rank'] = $t
print(json.dumps(d))" >> "$OUT/fmm.jsonl"
    echo "K=$k T=$t N=$n rc=$?"
}
run 1 1 "$WEAK_PER"
run 1 1 "$STRONG_N"
for k in 16 8 4 2 1; do
    [ "$k" -le "$CORES" ] && run "$k" $((CORES / k)) "$STRONG_N"
done
for k in 16 4 1; do
    [ "$k" -le "$CORES" ] && run "$k" $((CORES / k)) $((WEAK_PER * CORES))
done
python3 - "$OUT" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1] + "/fmm.jsonl")]
import os
wp = int(os.environ["WEAK_PER"])
base = {r["n_sources"]: r["eval_s"] for r in rows if r["ranks"] == 1 and r["threads_per_rank"] == 1}
w1 = base.get(wp)
with open(sys.argv[1] + "/ranks_threads.md", "w") as f:
    f.write("| N | K | T | setup s | eval s | comm s max | MB sent/rank max | top MB recv max "
            "| repeated far work max | imbalance | strong eff | weak eff |\n")
    f.write("|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    for r in rows:
        n, k, t, ev = r["n_sources"], r["ranks"], r["threads_per_rank"], r["eval_s"]
        cores = k * t
        strong = base[n] / (cores * ev) if n in base and cores > 1 else float("nan")
        weak = w1 / ev if w1 and n == wp * cores and cores > 1 else float("nan")
        f.write(f"| {n} | {k} | {t} | {r['setup_s']:.2f} | {ev:.3f} | {max(r['rank_comm_s']):.3f} | "
                f"{max(r['rank_bytes_sent']) / 1e6:.2f} | {max(r['rank_top_bytes_received']) / 1e6:.2f} | "
                f"{100 * max(r.get('rank_repeated_far_fraction', [0])):.1f} % | {r['load_imbalance']:.2f} | "
                f"{100 * strong:.0f} % | {100 * weak:.0f} % |\n")
print(open(sys.argv[1] + "/ranks_threads.md").read())
PY
