#!/usr/bin/env bash
# Is the DPD capsule's smaller deformation thermal? (docs/dpd_vs_bie.md, "The capsule at lower
# temperatures"). The capsule of scripts/dpd_vs_bie.sh (μ0 = 20, walls at ±0.7) at k_BT = 0.25
# and 0.1 with the conservative force scaled with the temperature (a = 25 k_BT: the same fluid
# structure, the same viscosity), the membrane's moduli unchanged, so μ0R²/k_BT = 720 and 1800
# instead of 180. First the viscosity of each fluid by periodic Poiseuille (`mobo dpd`, box
# 10 × 10 × 20, 40 000 steps), then the capsule with that viscosity in its capillary number,
# then the boundary-integral capsule at the capillary numbers measured. One thread per run;
# about an hour here.
#   bash scripts/dpd_capsule_temperature.sh > docs/dpd_capsule_temperature_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --bin mobo --example dpd_capsule_shear --example capsule_shear >&2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
export RAYON_NUM_THREADS=1
echo "# dpd_capsule_temperature $(date -u +%Y-%m-%d), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
for kbt in ${KBTS:-1 0.25 0.1}; do
    a=$(python3 -c "print(25 * $kbt)")
    sed "s/^gamma = 4.5/gamma = 45.0/; s/^kbt = 1.0/kbt = $kbt/; s/^a = 25.0/a = $a/; s/^power = 1.0/power = 0.25/; s/^dt = 0.01/dt = 0.002/; s/^steps = 20000/steps = 40000/; s/^force = 0.05/force = 0.1/; s/^equilibrate = 4000/equilibrate = 15000/; s/^save_every = 1000/save_every = 40000/" \
        examples/scenes/dpd_poiseuille.toml > "$tmp/pois.toml"
    ./target/release/mobo dpd "$tmp/pois.toml" --out "$tmp/pois_$kbt" > /dev/null 2>&1
    read -r eta stderr < <(python3 -c "import json; v = json.load(open('$tmp/pois_$kbt/summary.json'))['viscosity']; print(round(v['value'], 2), round(v['stderr'], 2))")
    echo "viscosity at k_BT $kbt, a $a: $eta ± $stderr"
    line=$(KBT=$kbt A=$a ETA=$eta ./target/release/examples/dpd_capsule_shear 0.7 20 "${STEPS:-100000}" "${SETTLE:-40000}" 1)
    echo "DPD: $line"
    ca=$(echo "$line" | sed -n 's/.*Ca = eta\*rate\*R\/mu0 = \([0-9.e-]*\);.*/\1/p')
    # capsule_shear takes Ramanujan & Pozrikidis' Ca = μγ̇a/E_s = Ca_G/3.
    echo "BIE: $(./target/release/examples/capsule_shear sk "$(python3 -c "print($ca / 3.0)")" 12 0.02 10 | tail -1)"
done
