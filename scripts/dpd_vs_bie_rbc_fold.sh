#!/usr/bin/env bash
# What folds the turned DPD red blood cell at its flips (docs/dpd_vs_bie.md, "What folds the
# DPD cell at its flips"): the turned cell of scripts/dpd_vs_bie_rbc_turned.sh with the local
# area penalty k_d ten times Fedosov's (`kd = 1000` in [dpd.from_cells]) in the channels 20 and
# 30 wide (there also with a second seed), and at k_BT = 0.25 in the channel 30 wide with the
# conservative force scaled with the temperature (a = 6.25, so a/k_BT and the fluid's viscosity
# stay as at k_BT = 1; the run of dpd_vs_bie_rbc_turned.sh kept a = 25, whose fluid is 1.5
# times as viscous). Sampled by
# examples/shear_both_ways.rs, one thread per run, two at a time, 125 000 steps each; about
# 2 hours here.
#   bash scripts/dpd_vs_bie_rbc_fold.sh > docs/dpd_vs_bie_rbc_fold_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/rbc_shear_common.sh
turned | local_area 1000.0 > "$tmp/gap20_kd1000.toml"
turned | widen 30 | local_area 1000.0 > "$tmp/gap30_kd1000.toml"
sed 's/^seed = 1/seed = 2/' "$tmp/gap30_kd1000.toml" > "$tmp/gap30_kd1000_seed2.toml"
turned | widen 30 | sed 's/^kbt = 1.0/kbt = 0.25/; s/^a = 25.0/a = 6.25/' > "$tmp/gap30_kbt0.25_a6.25.toml"
header dpd_vs_bie_rbc_fold
run_dpd gap30_kd1000 &
run_dpd gap20_kd1000 &
wait -n
run_dpd gap30_kbt0.25_a6.25 &
wait -n
run_dpd gap30_kd1000_seed2 &
wait
print_runs dpd_turned90_ gap20_kd1000 gap30_kd1000 gap30_kd1000_seed2 gap30_kbt0.25_a6.25
