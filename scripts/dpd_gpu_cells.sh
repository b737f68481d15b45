#!/usr/bin/env bash
# Cells in the DPD fluid with the solvent's pair forces on the GPU (`[dpd] gpu`, feature gpu),
# against the CPU path on the same machine, as measured for benches/RESULTS.md:
#
# * the RBC of examples/scenes/rbc_shear_bie_and_dpd.toml (18 480 particles, one cell of 642
#   vertices, Couette channel of gap 20, 300 warm-up steps): the CPU on all threads and on one,
#   the GPU in f32 and f64 (the membranes, the bounce-back and the coupling on all CPU threads,
#   and on one);
# * the same RBC in a channel 64 × 64 × 66 (gap 64, 786 432 particles before the walls
#   freeze, 50 warm-up steps), where the solvent is nearly all of the work.
#
#   scripts/dpd_gpu_cells.sh OUTDIR                      # builds mobo (feature gpu)
#   MOBO_BIN=path/to/mobo scripts/dpd_gpu_cells.sh OUTDIR  # a binary built elsewhere
#
# Environment: STEPS (steps of the RBC-scene runs on all threads, default 2000), ONE_STEPS (on
# one thread, default 300), BIG_GPU_STEPS and BIG_CPU_STEPS (the big channel, default 300 and
# 100), SKIP_BIG=1 (only the RBC scene). Prints one table row per run; each run's summary.json stays in OUTDIR/NAME.
set -uo pipefail
cd "$(dirname "$0")/.."
out="${1:?usage: scripts/dpd_gpu_cells.sh OUTDIR}"
mkdir -p "$out"
MOBO="${MOBO_BIN:-}"
if [ -z "$MOBO" ]; then
    cargo build --release --features gpu --bin mobo >&2
    MOBO=target/release/mobo
fi
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"

# The RBC scene with `steps` and the [dpd] lines `extra` (after wall_warmup).
rbc_scene() {
    awk -v steps="$1" -v extra="$2" '
        /^steps = 60000/ { print "steps = " steps; next }
        /^save_every = 5000/ { print "save_every = 1000000"; next }
        { print }
        /^wall_warmup = / { printf "%s", extra }
    ' examples/scenes/rbc_shear_bie_and_dpd.toml
}

# The same fluid and cell model in a 64 × 64 × 66 channel.
big_scene() {
    cat <<TOML
[dpd]
box = [64.0, 64.0, 66.0]
density = 3.0
a = 25.0
gamma = 45.0
power = 0.25
kbt = 1.0
dt = 0.002
steps = $1
seed = 1
walls = { kind = "planes", gap = 64.0 }
wall_warmup = 50
flow = "couette"
wall_speed = 3.78
save_every = 1000000
$2
[[dpd.cells]]
shape = "rbc"
radius = 3.0
center = [32.0, 32.0, 33.0]
subdivisions = 3
shear_modulus = 20.0
bending_rigidity = 2.0
TOML
}

row() { # name threads
    python3 - "$out/$1/summary.json" "$1" "$2" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
m = s.get("membranes") or {}
cell = (m.get("per_cell") or [{}])[0]
w = s.get("wall_warmup") or {}
fs = s["fluid_step"]
dev = fs["device"] + (" " + fs["precision"] if fs.get("precision") else "")
t = s["timings"]
steps_s = s["wall_s"]
print(f"| {sys.argv[2]} | {dev} | {sys.argv[3]} | {s['steps']} | {s['particles']} | "
      f"{s['ms_per_step']:.3f} | {s['particle_steps_per_second']:.3g} | "
      f"{t['forces_s'] / steps_s * 100:.0f} % | "
      f"{w.get('device', '-')} {w.get('precision') or ''} {w.get('seconds', float('nan')):.2f} s | "
      f"{m.get('bounces', '-')} | {m.get('leaked_particles', '-')} | "
      f"{cell.get('taylor_deformation', float('nan')):.4f} | {cell.get('inclination_deg', float('nan')):.1f} | "
      f"{s['temperature']:.4f} | " + " / ".join(
          f"{m.get('timings', {}).get(k, float('nan')) / s['steps'] * 1e3:.2f}"
          for k in ("bounce_s", "membrane_s", "coupling_s", "leaks_s")) + " |")
PY
}

run() { # name threads scene-text
    printf '%s' "$3" > "$out/$1.toml"
    if RAYON_NUM_THREADS="$2" "$MOBO" dpd "$out/$1.toml" --out "$out/$1" --quiet \
        > "$out/$1.log" 2>&1; then
        row "$1" "$2"
    else
        echo "| $1 | FAILED: $(tail -c 300 "$out/$1.log" | tr '\n' ' ') |"
    fi
}

all="$(nproc)"
gpu32=$'gpu = true\ngpu_precision = "f32"\n'
gpu64=$'gpu = true\ngpu_precision = "f64"\n'
cpu=$'gpu = false\n'
echo "| run | fluid step | threads | steps | particles | ms/step | particle-steps/s | pair forces % of the steps | warm-up | membrane bounces | leaked | D | inclination ° | k_BT | cells: bounce / membrane / coupling / leaks, ms per step |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
S="${STEPS:-2000}"
O="${ONE_STEPS:-300}"
run rbc-cpu "$all" "$(rbc_scene "$S" "$cpu")"
run rbc-gpu-f32 "$all" "$(rbc_scene "$S" "$gpu32")"
run rbc-gpu-f64 "$all" "$(rbc_scene "$S" "$gpu64")"
run rbc-cpu-1 1 "$(rbc_scene "$O" "$cpu")"
run rbc-gpu-f32-1 1 "$(rbc_scene "$O" "$gpu32")"
[ "${SKIP_BIG:-0}" = 1 ] && exit 0
run big-cpu "$all" "$(big_scene "${BIG_CPU_STEPS:-100}" "$cpu")"
run big-gpu-f32 "$all" "$(big_scene "${BIG_GPU_STEPS:-300}" "$gpu32")"
run big-gpu-f64 "$all" "$(big_scene "${BIG_GPU_STEPS:-300}" "$gpu64")"
