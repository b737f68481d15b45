#!/usr/bin/env bash
# Strong scaling of `mpirun -n K mobo brownian`: a cloud of BEADS beads (TEA-HI noise, overlap
# repulsion, the sub-cellular-element potential, gravity) on K = KS ranks, one rayon thread a
# rank by default. Each rank takes a block of rows of the O(N²) pass; the trajectory is
# checked to be the one-rank file, byte for byte, and a table (s/step, efficiency against the
# first K, rows and exchange seconds per rank, bytes per step) is appended to RESULTS.
#
#   BEADS=4000 KS="1 2" STEPS=20 scripts/brownian_scaling.sh
set -euo pipefail
cd "$(dirname "$0")/.."
beads=${BEADS:-4000}
ks=${KS:-"1 2"}
steps=${STEPS:-20}
threads=${THREADS:-1}
out=${OUT:-target/brownian-scaling}
results=${RESULTS:-benches/RESULTS.md}
. scripts/mpi_common.sh
mpi_setup scripts/brownian_scaling.sh "$threads" "$out"
# Number density of 300 beads in a 30³ box.
side=$(python3 -c "print(round(30 * (${beads} / 300) ** (1 / 3), 2))")
scene="$out/cloud_${beads}.toml"
# The example cloud at BEADS beads, the same density, STEPS steps.
sed -e "s/^beads = .*/beads = $beads/" -e "s/^box = .*/box = $side/" \
    -e "s/^steps = .*/steps = $steps/" -e "s/^save_every = .*/save_every = $steps/" \
    examples/scenes/brownian_cloud.toml >"$scene"
dirs=()
for k in $ks; do
    dir="$out/k$k"
    rm -rf "$dir"
    echo "scripts/brownian_scaling.sh: $beads beads, $k ranks" >&2
    mpirun --allow-run-as-root --oversubscribe -n "$k" "$MOBO_BIN" brownian "$scene" --out "$dir" --quiet >&2
    cmp -s "${dirs[0]:-$dir}/trajectory.npy" "$dir/trajectory.npy" || {
        echo "scripts/brownian_scaling.sh: $k ranks: trajectory differs from ${dirs[0]}" >&2
        exit 1
    }
    dirs+=("$dir")
done
table=$(python3 - "${dirs[@]}" <<'EOF'
import json, sys
runs = [json.load(open(f"{d}/summary.json")) for d in sys.argv[1:]]
def ranks(s): return (s["split"] or {"ranks": 1})["ranks"]
k0, t0 = ranks(runs[0]), runs[0]["wall_s"] / runs[0]["steps"]
print("| K | beads | s/step | efficiency | rows s/step (max/mean) | exchange s/step (max) | kB sent/step/rank | trajectory |")
print("|---|---|---|---|---|---|---|---|")
for s in runs:
    k, st, sp = ranks(s), s["steps"], s["split"]
    t = s["wall_s"] / st
    cols = (f"{sp['rows_s'][0]/st:.4f}/{sp['rows_s'][1]/st:.4f} | {sp['exchange_s'][0]/st:.4f} | {sp['bytes_per_step']/1e3:.0f}"
            if sp else "– | – | 0")
    print(f"| {k} | {s['beads']} | {t:.4f} | {t0 * k0 / (t * k):.2f} | {cols} | same bytes as K = {k0} |")
EOF
)
header="### Strong scaling of \`mpirun -n K mobo brownian\` — $(machine)

$beads beads, TEA-HI, repulsion + SCE + gravity, $steps steps, ${threads} rayon thread(s) per rank,
\`scripts/brownian_scaling.sh\` (BEADS=$beads KS=\"$ks\")."
publish scripts/brownian_scaling.sh "$header" "$table" "$results"
