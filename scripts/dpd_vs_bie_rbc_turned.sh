#!/usr/bin/env bash
# The turned red blood cell (axis in the shear plane) by DPD in wider channels and at a lower
# temperature (docs/dpd_vs_bie.md, "The turned cell in wider channels and at a lower
# temperature"), each run sampled by examples/shear_both_ways.rs, one thread per run:
#   walls 30 apart (box 32 high, wall speed 1.77), k_BT 1 and 0.25;
#   walls 40 apart (box 42 high, wall speed 2.36), k_BT 1.
# The same nominal shear rate as examples/scenes/rbc_shear_bie_and_dpd.toml (2U/gap = 0.118),
# 125 000 steps each. About 2 hours here with two runs at a time (the 40-wide run alone ~1.5 h).
#   bash scripts/dpd_vs_bie_rbc_turned.sh > docs/dpd_vs_bie_rbc_turned_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/rbc_shear_common.sh
turned | widen 30 > "$tmp/gap30.toml"
sed 's/^kbt = 1.0/kbt = 0.25/' "$tmp/gap30.toml" > "$tmp/gap30_kbt0.25.toml"
turned | widen 40 > "$tmp/gap40.toml"
header dpd_vs_bie_rbc_turned
run_dpd gap40 &
run_dpd gap30 &
wait -n
run_dpd gap30_kbt0.25 &
wait
print_runs dpd_turned90_ gap30 gap30_kbt0.25 gap40
