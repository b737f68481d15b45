#!/usr/bin/env bash
# Shows that a refactor changed no result: runs every example scene, shortened, with the release
# binary of REV and with that of the working tree, and compares what they wrote byte for byte:
# observables.csv, the frames (frames/*.npy, vtk/*.vtp, frames.h5), profile.csv, trajectory.npy,
# the checkpoint (less its wall clocks), scene.toml, and summary.json less its timings (every key that names a time
# measured by the clock: "timings", "*seconds*", "wall*", "*_s", "*per_second*", "*rate*", and the
# memory measured, "*rss*").
#
#   scripts/same_results.sh REV            # e.g. scripts/same_results.sh HEAD~3
#
# REV is built in a git worktree under target/same-results/ with its own target folder (the
# dependencies compile once and are kept for later calls). To compare binaries you built
# yourself: MOBO_BASE_BIN=/path/to/old/mobo MOBO_HEAD_BIN=/path/to/new/mobo scripts/same_results.sh.
# MOBO_SAME_KEEP=1 keeps the outputs (target/same-results/out/{base,head}/...).
#
# What runs (each on one thread, so that sums are in the same order):
#   * the built-in demo (`mobo run`, 4 steps);
#   * every scene of examples/scenes with [[cells]]: `mobo run --max-steps 4`, then
#     `mobo run --resume` for 2 more steps (checkpoint and restart take part);
#   * every scene with [dpd]: `mobo dpd --max-steps 30`, then `--resume` for 10 more;
#   * every scene with [brownian]: its `steps` cut to 40 (a copy of the scene).
# Exit status 0 when everything is identical, 1 when anything differs (the differing files are
# listed), 2 on a usage or build error.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD"
work="$root/target/same-results"
mkdir -p "$work"

rev="${1:-}"
base_bin="${MOBO_BASE_BIN:-}"
head_bin="${MOBO_HEAD_BIN:-}"
if [ -z "$base_bin" ]; then
    if [ -z "$rev" ]; then
        echo "usage: scripts/same_results.sh REV   (or set MOBO_BASE_BIN and MOBO_HEAD_BIN)" >&2
        exit 2
    fi
    sha="$(git rev-parse --verify "$rev^{commit}")" || { echo "same_results: no commit $rev" >&2; exit 2; }
    tree="$work/tree-$sha"
    if [ ! -d "$tree" ]; then
        git worktree add --detach "$tree" "$sha" >&2
    fi
    echo "same_results: building $rev ($sha) in $tree" >&2
    (cd "$tree" && CARGO_TARGET_DIR="$work/target" cargo build --release --quiet --bin mobo) || exit 2
    base_bin="$work/base-mobo"
    cp "$work/target/release/mobo" "$base_bin"
fi
if [ -z "$head_bin" ]; then
    echo "same_results: building the working tree" >&2
    cargo build --release --quiet --bin mobo || exit 2
    head_bin="$root/target/release/mobo"
fi

export RAYON_NUM_THREADS=1
export MOBO_OPERATOR_CACHE="${MOBO_OPERATOR_CACHE:-$root/target/operator-cache}"
out="$work/out"
rm -rf "$out"
mkdir -p "$out/base" "$out/head" "$out/scenes"

# The scenes, shortened where a key must change (brownian steps).
for f in examples/scenes/*.toml; do
    name="$(basename "$f" .toml)"
    if grep -q '^\[brownian\]' "$f"; then
        sed -E 's/^steps = [0-9]+/steps = 40/' "$f" >"$out/scenes/$name.toml"
    else
        cp "$f" "$out/scenes/$name.toml"
    fi
done
# The data files scenes name beside them (a wall's points, its velocities).
cp examples/scenes/*.npy "$out/scenes/" 2>/dev/null || true

# run_all BIN DIR: every run into DIR; a run's failure is recorded (its stderr), not fatal: a
# refactor must fail the same way.
run_all() {
    local bin="$1" dir="$2" f name
    run_one() { # label, then the command
        local label="$1"
        shift
        if ! "$@" >"$dir/$label.stdout" 2>"$dir/$label.stderr"; then
            echo "exit $?" >>"$dir/$label.failed"
        fi
    }
    run_one demo "$bin" run --quiet --out "$dir/demo" --max-steps 4
    for f in "$out"/scenes/*.toml; do
        name="$(basename "$f" .toml)"
        if grep -q '^\[\[cells\]\]' "$f"; then
            run_one "$name.run" "$bin" run --quiet "$f" --out "$dir/$name.run" --max-steps 4
            if [ -e "$dir/$name.run/checkpoint.bin" ]; then
                run_one "$name.run.resume" "$bin" run --quiet --resume "$dir/$name.run" --max-steps 2
            fi
        fi
        if grep -q '^\[dpd\]' "$f"; then
            run_one "$name.dpd" "$bin" dpd --quiet "$f" --out "$dir/$name.dpd" --max-steps 30
            if [ -e "$dir/$name.dpd/checkpoint.bin" ]; then
                run_one "$name.dpd.resume" "$bin" dpd --quiet --resume "$dir/$name.dpd" --max-steps 10
            fi
        fi
        if grep -q '^\[brownian\]' "$f"; then
            run_one "$name.brownian" "$bin" brownian --quiet "$f" --out "$dir/$name.brownian"
        fi
    done
}

echo "same_results: running the scenes with the base binary ($base_bin)" >&2
run_all "$base_bin" "$out/base"
echo "same_results: running the scenes with the new binary ($head_bin)" >&2
run_all "$head_bin" "$out/head"

# Compare: summary.json less timings; stdout less timings (the same filter, line by line, for
# the JSON lines some commands print); every other file byte for byte.
status=0
python3 - "$out/base" "$out/head" <<'EOF' || status=$?
import json, os, re, sys

base, head = sys.argv[1], sys.argv[2]
TIMED = re.compile(r"(timing|second|wall_time|elapsed|_s$|^ms_|_ms$|per_second|throughput|duration|rss)", re.I)

def strip(v):
    if isinstance(v, dict):
        return {k: strip(x) for k, x in v.items() if not TIMED.search(k)}
    if isinstance(v, list):
        return [strip(x) for x in v]
    return v

def mask(text, d=None):
    # durations and rates ("0.04 s", "(925 steps/s)") and the run's own folder
    text = text.replace(base, "<out>").replace(head, "<out>")
    return re.sub(r"[0-9.]+(e[-+]?[0-9]+)? ?(s|ms|µs|[A-Za-z-]+/s)\b", "<t>", text)

def checkpoint(p):
    """A checkpoint (src/io/checkpoint.rs, version 1) as (header, arrays) less its clocks."""
    import struct
    b = open(p, "rb").read()
    o = 8 + 4 + 8
    (h,) = struct.unpack_from("<Q", b, o); o += 8
    hdr = strip(json.loads(b[o:o + h])); o += h
    (na,) = struct.unpack_from("<Q", b, o); o += 8
    arrays = {}
    for _ in range(na):
        (nl,) = struct.unpack_from("<I", b, o); o += 4
        name = b[o:o + nl].decode(); o += nl
        (nd,) = struct.unpack_from("<I", b, o); o += 4
        dims = struct.unpack_from("<%dQ" % nd, b, o); o += 8 * nd
        count = 1
        for d in dims:
            count *= d
        if not (TIMED.search(name) or name == "clocks"):
            arrays[name] = (dims, b[o:o + 8 * count])
        o += 8 * count
    return hdr, arrays

def files(d):
    out = set()
    for r, _, fs in os.walk(d):
        for f in fs:
            out.add(os.path.relpath(os.path.join(r, f), d))
    return out

fb, fh = files(base), files(head)
bad = []
for f in sorted(fb ^ fh):
    bad.append(f"{f}: only in {'base' if f in fb else 'head'}")
n = 0
for f in sorted(fb & fh):
    pb, ph = os.path.join(base, f), os.path.join(head, f)
    n += 1
    if f.endswith(".stdout"):
        # progress and timing lines: JSON lines are compared less their timings
        a, b = open(pb).read().splitlines(), open(ph).read().splitlines()
        def norm(lines):
            out = []
            for l in lines:
                try:
                    out.append(json.dumps(strip(json.loads(l)), sort_keys=True))
                except ValueError:
                    out.append(mask(l))
            return out
        if norm(a) != norm(b):
            bad.append(f"{f}: stdout differs")
        continue
    if f.endswith(".stderr"):
        # errors must match; timing words are masked
        a = mask(open(pb).read())
        b = mask(open(ph).read())
        if a != b:
            bad.append(f"{f}: stderr differs")
        continue
    if os.path.basename(f) == "summary.json":
        a, b = strip(json.load(open(pb))), strip(json.load(open(ph)))
        if a != b:
            keys = [k for k in set(a) | set(b) if a.get(k) != b.get(k)]
            bad.append(f"{f}: differs in {sorted(keys)}")
        continue
    if os.path.basename(f) == "checkpoint.bin":
        (ha, aa), (hb, ab) = checkpoint(pb), checkpoint(ph)
        if ha != hb or aa != ab:
            bad.append(f"{f}: differs in {'the header, ' if ha != hb else ''}arrays {sorted(k for k in set(aa) | set(ab) if aa.get(k) != ab.get(k))}")
        continue
    if open(pb, "rb").read() != open(ph, "rb").read():
        bad.append(f"{f}: bytes differ")
print(f"same_results: {n} files compared in {len(os.listdir(base))} runs' outputs")
failed = sorted(f for f in fb if f.endswith(".failed"))
if failed:
    print("same_results: runs that failed (in both, the same way unless listed below): " + ", ".join(failed))
if bad:
    print("same_results: DIFFERENT:")
    for b in bad:
        print("  " + b)
    sys.exit(1)
print("same_results: identical")
EOF
if [ "${MOBO_SAME_KEEP:-0}" != 1 ] && [ "$status" = 0 ]; then
    rm -rf "$out"
fi
exit "$status"
