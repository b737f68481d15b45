#!/usr/bin/env bash
# Every example cell scene (examples/scenes/*.toml with [[cells]]) switched to order p = 12 and
# run 10× longer than shipped, with `mobo run` in release mode: prints a Markdown table of steps,
# final time, GMRES iterations per cell-step (mean, max), area/volume drift and wall time, and
# exits non-zero if a run fails. FACTOR (default 10) and ORDER (default 12) change the study.
#   scripts/examples_p12.sh | tee /tmp/examples_p12.md
set -uo pipefail
cd "$(dirname "$0")/.."
FACTOR=${FACTOR:-10}
ORDER=${ORDER:-12}
cargo build --release >&2 || exit 1
work=$(mktemp -d)
cp target/release/mobo "$work/mobo"
echo "Example scenes at p = $ORDER, t_end × $FACTOR ($(date -u +%Y-%m-%d), $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores):"
echo
echo "| scene | cells | steps | t_end | GMRES its mean | max | area drift | volume drift | wall s | result |"
echo "|---|---|---|---|---|---|---|---|---|---|"
status=0
for scene in examples/scenes/*.toml; do
  grep -q '^\[\[cells\]\]' "$scene" || continue
  name=$(basename "$scene" .toml)
  awk -v p="$ORDER" -v f="$FACTOR" '
    /^order *=/ { print "order = " p; next }
    /^t_end *=/ { split($0, a, "="); printf "t_end = %.10g\n", a[2] * f; next }
    { print }' "$scene" > "$work/$name.toml"
  out="$work/$name"
  if "$work/mobo" run "$work/$name.toml" --out "$out" --quiet > "$work/$name.log" 2>&1; then
    python3 - "$out/summary.json" "$name" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print(f"| {sys.argv[2]} | {s['cells']} | {s['steps']} | {s['final_time']:.4g} | "
      f"{s['gmres_iterations_mean']:.1f} | {s['gmres_iterations_max']} | {s['area_drift']:.1e} | "
      f"{s['volume_drift']:.1e} | {s['wall_s']:.0f} | {'finished' if s['completed'] else 'stopped'} |")
PY
  else
    status=1
    echo "| $name | | | | | | | | | FAILED: $(tail -1 "$work/$name.log" | cut -c1-200) |"
  fi
done
rm -rf "$work"
exit $status
