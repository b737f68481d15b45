#!/usr/bin/env bash
# The cost of a step against volume fraction, for each coupling mode (issue 51, item 5).
#
# 16 RBCs (Skalak, shear modulus 1, bending 0.1, viscosity ratio 5) packed with
# `placement = "packed"` at 10, 20, 30 and 45 % (gaps 0.05; 0.02 at 45 %, where 16 cells jam
# at about 42 % with 0.05), shear rate 1, p = 8, BDF2, dt = 0.01, contacts on
# (`contact_distance` = the packing gap), STEPS steps (default 60) with `coupling = "explicit"`
# and with `"near_implicit"`. Prints one Markdown table row per run: steps run (and the error
# when a run failed), seconds per step, GMRES iterations, contact moves and the contacts' share
# of the time, the smallest end-of-step gap.
#
#   scripts/dense_cost.sh            # release build, STEPS=60
#   STEPS=200 scripts/dense_cost.sh
#   PHIS="0.3 0.45" scripts/dense_cost.sh
#
# The largest stable dt: DTS="0.01 0.02 0.04 0.08" runs every case at each dt over the same
# time, STEPS × 0.01 (so STEPS steps at dt = 0.01, STEPS/8 at 0.08); COUNT and ORDER change the
# number of cells (16) and the order (8); COUPLINGS the modes (both). MOBO_BIN: a binary built
# already (no cargo build).
#
#   COUNT=8 ORDER=6 PHIS="0.2 0.3" DTS="0.01 0.02 0.04 0.08" STEPS=100 scripts/dense_cost.sh
set -euo pipefail
cd "$(dirname "$0")/.."
STEPS=${STEPS:-60}
COUNT=${COUNT:-16}
ORDER=${ORDER:-8}
if [ -n "${MOBO_BIN:-}" ]; then
  bin=$MOBO_BIN
else
  cargo build --release --quiet
  bin=target/release/mobo
fi
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
echo "| volume fraction | coupling | dt | steps run | s per step | GMRES iterations a step (mean, max) | contact moves (steps with moves) | contacts' share of the time | smallest end-of-step gap | area drift |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for phi in ${PHIS:-0.1 0.2 0.3 0.45}; do
  gap=0.05
  [ "$phi" = 0.45 ] && gap=0.02
  for coupling in ${COUPLINGS:-explicit near_implicit}; do
  for dt in ${DTS:-0.01}; do
    steps=$(python3 -c "print(max(1, round($STEPS * 0.01 / $dt)))")
    scene="$dir/dense_${phi}_${coupling}_${dt}.toml"
    cat > "$scene" <<EOF
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
count = $COUNT
placement = "packed"
volume_fraction = $phi
min_gap = $gap
seed = 7
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 5.0
[numerics]
order = $ORDER
dt = $dt
t_end = 100.0
scheme = "bdf2"
coupling = "$coupling"
contact_distance = $gap
[output]
every = $steps
vtk = false
npy = false
EOF
    out="$dir/out_${phi}_${coupling}_${dt}"
    if ! "$bin" run "$scene" --out "$out" --quiet --max-steps "$steps" >/dev/null 2>"$out.err" \
        && [ ! -f "$out/summary.json" ]; then
      echo "| $phi | $coupling | $dt | not run: $(head -c 160 "$out.err") | – | – | – | – | – | – |"
      continue
    fi
    python3 - "$out" "$phi" "$coupling" "$out.err" "$dt" <<'PY'
import json, sys
out, phi, coupling, err, dt = sys.argv[1:6]
s = json.load(open(out + "/summary.json"))
if "error" in s:
    steps = s["last_good_step"]
    msg = s["error"].split(": ", 1)[-1][:90]
    print(f"| {float(phi)*100:.0f} % | {coupling} | {dt} | {steps}, then fails: {msg} | – | – | – | – | – | – |")
    sys.exit(0)
steps = s["steps"]
c = s["counters"]["contacts"]
wall = s["wall_s"]
share = 100.0 * c["seconds"] / wall if wall > 0 else 0.0
gap = c["smallest_gap"]
gap = f"{gap:.4f}" if gap is not None else "–"
print(f"| {float(phi)*100:.0f} % | {coupling} | {dt} | {steps} | {wall/steps:.2f} | "
      f"{s['gmres_iterations_mean']:.1f}, {s['gmres_iterations_max']} | "
      f"{c['moves']} ({c['steps_with_moves']}) | {share:.1f} % | {gap} | {s['area_drift']:.1e} |")
PY
  done
  done
done
