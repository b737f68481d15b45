#!/usr/bin/env bash
# Whole time steps of RBC suspensions in shear (benches/step.rs): cell-steps per core-second at
# p = 6 and p = 12 for 1, 100 and 1000 cells, phase shares, GMRES iterations, peak RSS, beside
# faer's GEMM rate measured in the same run and MOBO's ~6–7 cell-steps per core-second (p = 6).
#
#   scripts/bench_step.sh [CONFIG ...]     # CONFIG = ORDERxCELLS, default 6x1 6x100 6x1000 12x1 12x100
#
# Environment: RAYON_NUM_THREADS (default 1: rate per core), STEP_BENCH_STEPS (timed steps per
# configuration; default as many as fit ~20 s of one thread), STEP_BENCH_PRECONDITIONER
# ("sphere", the default, or "cell": [numerics] preconditioner), CARGO_TARGET_DIR as usual.
# 12x1000 is left out by default for its time (about a minute per step on one thread and a
# warm-up step of several, peak RSS ~2.4 GB; benches/RESULTS.md): the dense operators now live
# per thread, not per cell, so it fits in memory.
# The table goes to stdout and, with the raw JSON lines of each configuration, to
# $TMPDIR/bench_step_<date>.log (default /tmp).
set -euo pipefail
cd "$(dirname "$0")/.."
log="${TMPDIR:-/tmp}/bench_step_$(date -u +%Y%m%dT%H%M%SZ).log"
export RAYON_NUM_THREADS="${RAYON_NUM_THREADS:-1}"
{
  echo "# $(date -u) $(uname -srm) git $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
  cargo bench --bench step -- "$@" 2>&1
} | tee "$log"
echo "log: $log" >&2
