#!/usr/bin/env bash
# Strong and weak scaling of `mpirun -n K mobo run` on a suspension of red blood cells.
#
#   scripts/scaling.sh strong     # a fixed suspension (CELLS cells) on K = KS ranks
#   scripts/scaling.sh weak       # CELLS cells per rank on K = KS ranks
#
# Settings (environment): KS (rank counts, default "1 2"), CELLS (default: strong 125, weak
# 60), ORDER (SH order p, default 6), STEPS (default 10), THREADS (rayon threads per rank,
# default 1: one core a rank), OUT (work directory, default target/scaling), RESULTS (the
# file the table is appended to, default benches/RESULTS.md; "-" prints it only). The last
# column is each rank's peak resident memory (summary.json's split.peak_rss_mib).
# MOBO_BIN: a prebuilt binary with the mpi feature (no cargo build).
# The cells are placed at random at a volume fraction of about 6 % (the box grows with the
# cell count); the flow is simple shear. Each run's summary.json gives the phases per rank
# (largest and mean), bytes sent per step and the solve imbalance; efficiency is
# T(K_min)·K_min / (T(K)·K) for strong and T(K_min)/T(K) for weak scaling, T the wall time
# per step.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-}
case "$mode" in
strong) cells=${CELLS:-125} ;;
weak) cells=${CELLS:-60} ;;
*)
    echo "usage: scripts/scaling.sh strong|weak" >&2
    exit 2
    ;;
esac
ks=${KS:-"1 2"}
order=${ORDER:-6}
steps=${STEPS:-10}
threads=${THREADS:-1}
out=${OUT:-target/scaling}
results=${RESULTS:-benches/RESULTS.md}
. scripts/mpi_common.sh
mpi_setup scripts/scaling.sh "$threads" "$out"
rows=()
for k in $ks; do
    n=$cells
    [ "$mode" = weak ] && n=$((cells * k))
    # Box side for ~6 % volume fraction of unit-radius cells (volume 4.19 each).
    side=$(python3 -c "print(round((${n} * 4.19 / 0.06) ** (1 / 3), 3))")
    half=$(python3 -c "print(${side} / 2)")
    scene="$out/${mode}_${n}_p${order}.toml"
    cat >"$scene" <<EOF
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
radius = 1.0
count = $n
placement = "random"
region = [[-$half, -$half, -$half], [$half, $half, $half]]
seed = 7
bending_modulus = 0.1
shear_modulus = 1.0

[numerics]
order = $order
dt = 0.02
t_end = $(python3 -c "print(0.02 * ${steps})")
gmres_tol = 1e-6
fmm_digits = 5

[output]
every = $steps
vtk = false
EOF
    dir="$out/${mode}_k${k}"
    rm -rf "$dir"
    echo "scripts/scaling.sh: $mode, $n cells, p = $order, $k ranks" >&2
    mpirun --allow-run-as-root --oversubscribe -n "$k" "$MOBO_BIN" run "$scene" --out "$dir" --quiet >&2
    rows+=("$k $n $dir")
done
table=$(python3 - "$mode" "$order" "$steps" "${rows[@]}" <<'EOF'
import json, sys
mode, order, steps = sys.argv[1], sys.argv[2], int(sys.argv[3])
runs = []
for r in sys.argv[4:]:
    k, n, d = r.split()
    s = json.load(open(f"{d}/summary.json"))
    runs.append((int(k), int(n), s))
k0, _, s0 = runs[0]
t0 = s0["step_s"] / s0["steps"]
print(f"| K | cells | cells/rank min–max | s/step | efficiency | solve s/step (max/mean) | coupling s/step (max) | FMM s/step (max) | near + ghosts s/step (max) | MB sent/step/rank (FMM, ghosts) | ghost cells/rank | solve imbalance | re-balances | peak MiB/rank (max/mean) |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for k, n, s in runs:
    sp, st = s["split"], s["steps"]
    t = s["step_s"] / st
    eff = (t0 * k0) / (t * k) if mode == "strong" else t0 / t
    per = lambda a: a / st
    print(
        f"| {k} | {n} | {sp['cells_per_rank'][0]:.0f}–{sp['cells_per_rank'][2]:.0f} | {t:.3f} | {eff:.2f} "
        f"| {per(sp['solve_s'][0]):.3f}/{per(sp['solve_s'][1]):.3f} | {per(sp['coupling_s'][0]):.3f} "
        f"| {per(sp['fmm_s'][0]):.3f} | {per(sp['near_s'][0] + sp['ghost_exchange_s'][0]):.3f} "
        f"| {sp['fmm_bytes_per_step'][0] / 1e6:.2f}, {sp['ghost_bytes_per_step'][0] / 1e6:.2f} "
        f"| {sp['ghost_cells_per_step'][0]:.0f} | {sp['solve_imbalance']:.2f} | {len(sp['rebalances'])} "
        f"| {sp.get('peak_rss_mib', [0, 0])[0]:.0f}/{sp.get('peak_rss_mib', [0, 0])[1]:.0f} |"
    )
EOF
)
header="### ${mode^} scaling of \`mpirun -n K mobo run\` — $(machine)

RBC suspension (Skalak), p = $order, $steps steps of dt = 0.02, FMM 5 digits, GMRES 1e-6,
${threads} rayon thread(s) per rank, \`scripts/scaling.sh $mode\` (KS=\"$ks\", CELLS=$cells)."
publish scripts/scaling.sh "$header" "$table" "$results"
