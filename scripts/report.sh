#!/usr/bin/env bash
# Regenerates the accuracy-versus-time report committed in docs/accuracy/ (accuracy.csv,
# accuracy.md, accuracy.png) with the default study: the built-in two-RBC scene, budget
# 10 minutes (pass other `mobo report accuracy` options as arguments, e.g. --budget-minutes 20).
# The plot needs a TrueType font (apt `fonts-dejavu-core`, or MOBO_FONT=/path/to/font.ttf).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo run --release -- report accuracy --out docs/accuracy "$@"
