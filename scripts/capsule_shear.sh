#!/usr/bin/env bash
# Capsule in simple shear: steady Taylor deformation against Ca for the neo-Hookean and the
# Skalak (C = 1) laws, the table of docs/capsules.md. One release build, one run per row
# (about a minute each at p = 12 on one core). Usage:
#   P=12 DT=0.02 T_END=10 bash scripts/capsule_shear.sh > docs/capsule_shear_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
P=${P:-12}
DT=${DT:-0.02}
T_END=${T_END:-10}
cargo build --release --example capsule_shear >&2
echo "# capsule_shear p=$P dt=$DT t_end=$T_END, $(date -u +%Y-%m-%d), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
for law in nh sk; do
    for ca in 0.0125 0.025 0.05 0.1 0.2; do
        ./target/release/examples/capsule_shear "$law" "$ca" "$P" "$DT" "$T_END" | tail -1
    done
done
