#!/usr/bin/env bash
# The DPD fluid's step on the GPU against the CPU's on the same machine, in one run; prints
# Markdown tables for benches/RESULTS.md.
#
#   scripts/dpd_gpu_bench.sh                  # builds examples/dpd_gpu_bench (feature gpu), runs it
#   MOBO_BENCH_BIN=path scripts/dpd_gpu_bench.sh   # a binary built elsewhere (a GPU machine without
#                                                  # cargo: carry it and the Vulkan loader, docs/gpu.md)
#
# Environment: CASES (boxes and densities, default "32:3 32:8 64:3 64:8"), STEPS (timed GPU
# steps, default 500), CPU_STEPS (timed CPU steps, default 10), POWERS (kernel exponents,
# default "1 0.25"), THREADS_ALL (CPU threads, default all).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${MOBO_BENCH_BIN:-}"
if [ -z "$BIN" ]; then
    cargo build --release --features gpu --example dpd_gpu_bench >&2
    BIN=target/release/examples/dpd_gpu_bench
fi
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
ALL="${THREADS_ALL:-$(nproc)}"
echo "## DPD fluid on the GPU, $(date -u +%Y-%m-%d), $(uname -n)"
echo
if command -v nvidia-smi >/dev/null 2>&1; then
    echo "GPU: $(nvidia-smi --query-gpu=name,clocks.max.sm,memory.total --format=csv,noheader | head -1)"
fi
echo "CPU: $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)), $ALL threads"
echo
for k in ${POWERS:-1 0.25}; do
    echo "### a = 25, γ = 4.5, k_BT = 1, r_c = 1, k = $k, dt = 0.01"
    echo
    # shellcheck disable=SC2086
    POWER="$k" RAYON_NUM_THREADS="$ALL" "$BIN" ${CASES:-32:3 32:8 64:3 64:8}
    echo
done
