#!/usr/bin/env bash
# GPU near field against the CPU in one run (issue 18's measurements); prints Markdown tables
# for benches/RESULTS.md.
#
#   scripts/gpu_bench.sh            # builds examples/gpu_bench (feature gpu) and runs it here
#   MOBO_BENCH_BIN=path scripts/gpu_bench.sh   # a binary built elsewhere (a GPU machine
#                                              # without cargo: carry the binary and the Vulkan
#                                              # loader, see docs/gpu.md)
#
# Environment: N_P2P (points of the all-pairs rates, default 131072), N_FMM (points of the FMM
# runs, default 1000000), THREADS_ALL (CPU threads of the GPU machine's runs, default all),
# FMM_CASES (which FMM rows; default all below), PEAK_F32_TFLOPS / PEAK_F64_TFLOPS (the GPU's
# peaks, printed beside the rates; nvidia-smi's name picks them for H100/H200 when unset).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${MOBO_BENCH_BIN:-}"
if [ -z "$BIN" ]; then
    cargo build --release --features gpu --example gpu_bench >&2
    BIN=target/release/examples/gpu_bench
fi
N_P2P="${N_P2P:-131072}"
N_FMM="${N_FMM:-1000000}"
ALL="${THREADS_ALL:-$(nproc)}"
export MOBO_OPERATOR_CACHE="${MOBO_OPERATOR_CACHE:-$PWD/target/operator-cache}"
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"

echo "## GPU near field, $(date -u +%Y-%m-%d), $(uname -n)"
echo
if command -v nvidia-smi >/dev/null 2>&1; then
    gpu_name="$(nvidia-smi --query-gpu=name,clocks.max.sm,memory.total --format=csv,noheader | head -1)"
    echo "GPU: $gpu_name; CPU: $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs))"
    case "$gpu_name" in
        *H100*PCIe*) : "${PEAK_F32_TFLOPS:=51.2}" "${PEAK_F64_TFLOPS:=25.6}" ;;
        *H100*|*H200*) : "${PEAK_F32_TFLOPS:=66.9}" "${PEAK_F64_TFLOPS:=33.5}" ;;
    esac
else
    echo "CPU: $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs))"
fi
echo "Peaks (vendor, non-tensor): f32 ${PEAK_F32_TFLOPS:-?} TFLOP/s, f64 ${PEAK_F64_TFLOPS:-?} TFLOP/s"
echo
echo "### Pair rates, all pairs of $N_P2P uniform points (GPU kernel alone; CPU on $ALL threads, same points)"
echo
RAYON_NUM_THREADS="$ALL" "$BIN" p2p "$N_P2P"
echo
echo "### TEA-HI fused pass, all pairs of $N_P2P beads (GPU pass alone; CPU AVX2 pass on $ALL threads)"
echo
RAYON_NUM_THREADS="$ALL" "$BIN" tea-hi "$N_P2P"
echo
echo "### FMM on $N_FMM points (best of 3 evaluations; error vs direct sums at 200 targets)"
echo
echo "| kernel | cloud | N | digits | order | leaf | threads | near field | error | setup s | eval s | near s | far wall s | near pairs |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
run() { # threads kernel cloud digits mode [leaf factor]
    local t="$1"; shift
    RAYON_NUM_THREADS="$t" "$BIN" fmm "$1" "$2" "$N_FMM" "$3" "$4" "${5:-1}"
}
CASES="${FMM_CASES:-stokeslet:6 laplace:6 stokeslet:3 laplace:3}"
for c in $CASES; do
    k="${c%%:*}"; d="${c##*:}"
    run "$ALL" "$k" spheres "$d" cpu
    run "$ALL" "$k" spheres "$d" gpu
    [ "$d" -le 5 ] && run "$ALL" "$k" spheres "$d" gpu32
    run "$ALL" "$k" spheres "$d" gpu 4
    run 2 "$k" spheres "$d" cpu
    run 2 "$k" spheres "$d" gpu 4
done
