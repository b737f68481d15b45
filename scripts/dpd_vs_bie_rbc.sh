#!/usr/bin/env bash
# The same red blood cell in shear by the boundary-integral solver and by DPD, from one scene
# file (examples/scenes/rbc_shear_bie_and_dpd.toml; docs/dpd_vs_bie.md, "A red blood cell"),
# each run sampled by examples/shear_both_ways.rs, one thread per run, two at a time:
#   DPD: the file as it is (the disk in the shear plane, walls 20 apart); the walls 30 apart;
#        at rest; turned by `orientation = [1, 0, 0, 90]` (the axis in the shear plane).
#   BIE: the file at p = 12 and 16; at the Ca the two DPD disk runs measured (0.104, 0.108 on
#        2026-11-27); turned by 90° and by 80°.
# About an hour here (the turned DPD run: 125 000 steps).
#   bash scripts/dpd_vs_bie_rbc.sh > docs/dpd_vs_bie_rbc_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/rbc_shear_common.sh
turned 90 > "$tmp/turned90.toml"
turned 80 > "$tmp/turned80.toml"
sed 's/^order = 12/order = 16/' "$scene" > "$tmp/p16.toml"
widen 30 < "$scene" > "$tmp/gap30.toml"
sed '/^wall_speed = /d; /^flow = "couette"/d; s/^steps = 60000/steps = 20000/' "$scene" > "$tmp/rest.toml"
for ca in 0.104 0.108; do
    sed "s/^shear_modulus = 10.0/shear_modulus = $(python3 -c "print(1/$ca)")/; s/^bending_modulus = 0.5/bending_modulus = $(python3 -c "print(0.05/$ca)")/" \
        "$scene" > "$tmp/ca$ca.toml"
done
run() { # $1: name, then the example's arguments
    local name=$1
    shift
    RAYON_NUM_THREADS=1 ./target/release/examples/shear_both_ways "$@" > "$tmp/$name.txt"
}
header dpd_vs_bie_rbc
run dpd_disk "$scene" dpd 100 4 &
run dpd_turned90 "$tmp/turned90.toml" dpd 100 4 &
wait
run dpd_disk_gap30 "$tmp/gap30.toml" dpd 100 4 &
run dpd_rest "$tmp/rest.toml" dpd 100 -1 &
wait
run bie_disk "$scene" bie 25 2 &
run bie_disk_p16 "$tmp/p16.toml" bie 25 2 &
wait
run bie_disk_ca0.104 "$tmp/ca0.104.toml" bie 25 2 &
run bie_disk_ca0.108 "$tmp/ca0.108.toml" bie 25 2 &
wait
run bie_turned90 "$tmp/turned90.toml" bie 25 10 &
run bie_turned80 "$tmp/turned80.toml" bie 25 10 &
wait
print_runs "" bie_disk bie_disk_p16 bie_disk_ca0.104 bie_disk_ca0.108 dpd_disk dpd_disk_gap30 dpd_rest \
    bie_turned90 bie_turned80 dpd_turned90
