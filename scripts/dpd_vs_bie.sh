#!/usr/bin/env bash
# The same spherical capsule in shear by DPD and by the boundary-integral solver
# (docs/dpd_vs_bie.md): the DPD runs at rest and at two wall speeds, then the BIE capsule
# (Skalak C = 1, the same small-strain shear and area moduli) at the capillary numbers the
# DPD runs measured. One thread each; about 45 minutes here (the DPD runs need γ̇t ≈ 5 to
# settle: 100 000 steps of dt = 0.002).
#   bash scripts/dpd_vs_bie.sh > docs/dpd_vs_bie_runs.txt
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --example dpd_capsule_shear --example capsule_shear >&2
echo "# dpd_vs_bie $(date -u +%Y-%m-%d), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
export RAYON_NUM_THREADS=1
for u in ${SPEEDS:-0 0.35 0.7}; do
    line=$(./target/release/examples/dpd_capsule_shear "$u" 20 "${STEPS:-100000}" "${SETTLE:-40000}" 1)
    echo "DPD: $line"
    ca=$(echo "$line" | sed -n 's/.*Ca = eta\*rate\*R\/mu0 = \([0-9.e-]*\);.*/\1/p')
    if [ "$u" != "0" ] && [ -n "$ca" ]; then
        # capsule_shear takes Ramanujan & Pozrikidis' Ca = μγ̇a/E_s = Ca_G/3.
        ca_rp=$(python3 -c "print($ca / 3.0)")
        echo "BIE: $(./target/release/examples/capsule_shear sk "$ca_rp" 12 0.02 10 | tail -1)"
    fi
done
