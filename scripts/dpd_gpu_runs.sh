#!/usr/bin/env bash
# The DPD fluid on a GPU machine, as measured for benches/RESULTS.md and docs/dpd_gpu_validation.md:
# the validation runs of docs/dpd_validation.md with every step on the GPU, and `mobo dpd` on a
# 64³ periodic-Poiseuille scene (786 432 particles) with the profile sampled every 10 and every
# 100 steps (each sample syncs the state to the host), against the CPU path on the same machine.
#
#   scripts/dpd_gpu_runs.sh OUTDIR        # builds what it needs (feature gpu)
#   MOBO_BIN=... VALIDATION_BIN=... scripts/dpd_gpu_runs.sh OUTDIR   # binaries built elsewhere
#
# Then the wall flows of docs/dpd.md's table on the GPU (a channel of gap 12 r_c and a pipe of
# radius 6 r_c, the viscosity between the walls, f32 and f64), and a 64 × 64 × 66 channel
# (gap 64) on the GPU against the CPU for speed.
#
# Environment: GPU_STEPS (steps of the 64³ GPU runs, default 3000), CPU_STEPS (of the CPU run,
# default 300), WALL_STEPS and WALL_EQ (steps and discarded steps of the gap-12 and radius-6
# runs, default 30000 and 10000), SKIP_VALIDATION=1, SKIP_PERIODIC=1 (the 64³ periodic runs),
# SKIP_WALLS=1, WALL_SEEDS (seeds of the gap-12 and radius-6 runs, default "2"; the 64-gap channel
# always runs seed 2; SKIP_BIG_CHANNEL=1 leaves it out).
set -uo pipefail
cd "$(dirname "$0")/.."
out="${1:?usage: scripts/dpd_gpu_runs.sh OUTDIR}"
mkdir -p "$out"
MOBO="${MOBO_BIN:-}"
VAL="${VALIDATION_BIN:-}"
if [ -z "$MOBO" ] || [ -z "$VAL" ]; then
    cargo build --release --features gpu --bin mobo --example dpd_gpu_validation >&2
    MOBO=target/release/mobo
    VAL=target/release/examples/dpd_gpu_validation
fi
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
if [ "${SKIP_VALIDATION:-0}" != 1 ]; then
    RUN_DATE="$(date -u +%Y-%m-%d)" "$VAL" > "$out/dpd_gpu_validation.md"
    echo "validation exit $?" >&2
fi
scene() { # steps, sample_every, gpu
    cat <<TOML
[dpd]
box = [64.0, 64.0, 64.0]
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.01
steps = $1
seed = 1
flow = "periodic_poiseuille"
force = 0.005
equilibrate = $(($1 / 3))
sample_every = $2
blocks = 5
bins = 32
save_every = 1000
gpu = $3
TOML
}
{
    echo "| device | steps | sample_every | ms/step | particle-steps/s | fluid_step | η | k_BT |"
    echo "|---|---|---|---|---|---|---|---|"
    [ "${SKIP_PERIODIC:-0}" = 1 ] || for run in "true ${GPU_STEPS:-3000} 10" "true ${GPU_STEPS:-3000} 100" "false ${CPU_STEPS:-300} 10"; do
        set -- $run
        name="gpu$1-$3"
        scene "$2" "$3" "$1" > "$out/$name.toml"
        "$MOBO" dpd "$out/$name.toml" --out "$out/$name" --quiet || echo "run $name failed" >&2
        python3 - "$out/$name/summary.json" "$1" "$2" "$3" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
v = s.get("viscosity") or {}
fs = s["fluid_step"]
print(f"| {fs['device']} {fs.get('precision') or ''} | {sys.argv[3]} | {sys.argv[4]} | {s['ms_per_step']:.3f} | "
      f"{s['particle_steps_per_second']:.3e} | {fs.get('adapter') or ''} | "
      f"{v.get('value', float('nan')):.3f} ± {v.get('stderr', float('nan')):.3f} | {s['temperature']:.4f} |")
PY
    done
} | tee "$out/mobo_dpd.md"

[ "${SKIP_WALLS:-0}" = 1 ] && exit 0
walled() { # box, walls, steps, equilibrate, gpu, precision, warmup, seed
    cat <<TOML
[dpd]
box = $1
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.01
steps = $3
seed = $8
flow = "poiseuille"
force = 0.05
equilibrate = $4
sample_every = 10
blocks = 10
bins = 24
save_every = 1000
walls = $2
wall_warmup = $7
gpu = $5
gpu_precision = "$6"
TOML
}
ws="${WALL_STEPS:-30000}"
we="${WALL_EQ:-10000}"
{
    echo "| flow | device | steps | ms/step | particle-steps/s | η | bounces | leaked | k_BT |"
    echo "|---|---|---|---|---|---|---|---|---|"
    runs=()
    for seed in ${WALL_SEEDS:-2}; do
        runs+=(
            "channel12-f32-s$seed|[10.0, 10.0, 14.0]|{ kind = \"planes\", gap = 12.0 }|$ws|$we|true|f32|300|$seed"
            "channel12-f64-s$seed|[10.0, 10.0, 14.0]|{ kind = \"planes\", gap = 12.0 }|$ws|$we|true|f64|300|$seed"
            "pipe6-f32-s$seed|[10.0, 14.0, 14.0]|{ kind = \"cylinder\", radius = 6.0 }|$ws|$we|true|f32|300|$seed"
            "pipe6-f64-s$seed|[10.0, 14.0, 14.0]|{ kind = \"cylinder\", radius = 6.0 }|$ws|$we|true|f64|300|$seed"
        )
    done
    [ "${SKIP_BIG_CHANNEL:-0}" = 1 ] || runs+=(
        "channel64-gpu|[64.0, 64.0, 66.0]|{ kind = \"planes\", gap = 64.0 }|${GPU_STEPS:-3000}|1000|true|f32|50|2"
        "channel64-cpu|[64.0, 64.0, 66.0]|{ kind = \"planes\", gap = 64.0 }|${CPU_STEPS:-300}|100|false|f32|50|2"
    )
    for run in "${runs[@]}"; do
        IFS='|' read -r name box wall steps eq gpu prec warm seed <<< "$run"
        walled "$box" "$wall" "$steps" "$eq" "$gpu" "$prec" "$warm" "$seed" > "$out/$name.toml"
        "$MOBO" dpd "$out/$name.toml" --out "$out/$name" --quiet > /dev/null || echo "run $name failed" >&2
        python3 - "$out/$name/summary.json" "$name" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
v = s.get("viscosity") or {}
fs = s["fluid_step"]
print(f"| {sys.argv[2]} | {fs['device']} {fs.get('precision') or ''} | {s['steps']} | {s['ms_per_step']:.3f} | "
      f"{s['particle_steps_per_second']:.3e} | {v.get('value', float('nan')):.3f} ± {v.get('stderr', float('nan')):.3f} | "
      f"{s['bounces']} | {s['leaked_particles']} | {s['temperature']:.4f} |")
PY
    done
} | tee "$out/walls.md"
