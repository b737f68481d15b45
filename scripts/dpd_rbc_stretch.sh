#!/usr/bin/env bash
# RBC optical-tweezers stretching (DPD membrane model) against Mills et al. (2004):
# runs the ignored table test in release and writes docs/dpd_rbc_stretch.md.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --release --test dpd_membrane -- --ignored --nocapture rbc_stretching_table
echo "wrote docs/dpd_rbc_stretch.md"
