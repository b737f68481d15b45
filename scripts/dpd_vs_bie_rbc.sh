#!/usr/bin/env bash
# The same red blood cell in shear by the boundary-integral solver and by DPD, from one scene
# file (examples/scenes/rbc_shear_bie_and_dpd.toml; docs/dpd_vs_bie.md, "The red blood cell"):
# the disk in the shear plane (it tank-treads) as the file has it, then turned by
# `orientation = [1, 0, 0, 90]` (its axis in the shear plane: it tumbles), each by both
# solvers, sampled by examples/shear_both_ways.rs. One thread per run, two runs at a time;
# about 40 minutes here (the DPD runs: 60 000 and 125 000 steps).
#   bash scripts/dpd_vs_bie_rbc.sh > docs/dpd_vs_bie_rbc_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --example shear_both_ways >&2
scene=examples/scenes/rbc_shear_bie_and_dpd.toml
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sed 's/^radius = 1.0/radius = 1.0\norientation = [1, 0, 0, 90]/; s/^steps = 60000/steps = 125000/; s/^t_end = 4.0/t_end = 40.0/' \
    "$scene" > "$tmp/tumbling.toml"
sed 's/^order = 12/order = 16/' "$scene" > "$tmp/p16.toml"
run() { RAYON_NUM_THREADS=1 ./target/release/examples/shear_both_ways "$@"; }
echo "# dpd_vs_bie_rbc $(date -u +%Y-%m-%d), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
run "$scene" dpd 100 4 > "$tmp/dpd_disk.txt" &
run "$tmp/tumbling.toml" dpd 100 4 > "$tmp/dpd_tumbling.txt" &
wait
run "$scene" bie 25 2 > "$tmp/bie_disk.txt" &
run "$tmp/p16.toml" bie 25 2 > "$tmp/bie_disk_p16.txt" &
wait
run "$tmp/tumbling.toml" bie 25 10 > "$tmp/bie_tumbling.txt"
for f in bie_disk bie_disk_p16 dpd_disk bie_tumbling dpd_tumbling; do
    echo "## $f: t strain D inclination tank_treading_rate/shear_rate shear_rate"
    cat "$tmp/$f.txt"
done
