#!/usr/bin/env bash
# Runs the whole default test suite (unit, integration, property and doc tests).
# Long studies (accuracy tables, scaling) are #[ignore]d; run them with
#   cargo test --release -- --ignored
set -euo pipefail
cd "$(dirname "$0")/.."
# Default features need nothing beyond cargo. Features with system libraries (mpi, gpu, hdf5)
# will install their packages here when they exist.
cargo test --all-features "$@"
