#!/usr/bin/env bash
# The FMM's loops against their rooflines and mobo fmm against FMM3D on another machine (the
# device machine: no cargo, no network). Build here and carry the binaries and the wheel:
#
#   cargo build --release --bin mobo --example m2l_roofline --example p2p_roofline
#   mkdir -p .devbin && cp target/release/mobo target/release/examples/{m2l,p2p}_roofline .devbin/
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#       --implementation cp --platform manylinux_2_28_x86_64 -d .whl fmm3dpy==2.1.0
#
# then run `bash scripts/device_fmm_rooflines.sh` there with .devbin and .whl carried; the tables
# land in $OUT (default ./device-out).
set -u
OUT=${OUT:-device-out}
mkdir -p "$OUT"
chmod +x .devbin/*
{ nproc; lscpu | grep -E "Model name|MHz|L1d|L2|L3"; grep -o -w -E "avx512f|avx512dq|avx512vl|avx2|fma" /proc/cpuinfo | sort | uniq -c; date -u; } > "$OUT/cpu.txt" 2>&1
( timeout 240 .devbin/m2l_roofline > "$OUT/m2l.md" 2>&1 ); echo "m2l rc $?"
( timeout 60 .devbin/p2p_roofline 2048 5 > "$OUT/p2p.md" 2>&1 ); echo "p2p rc $?"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site || exit
mkdir -p target/release && cp .devbin/mobo target/release/mobo
for th in 16 2; do
  ( RAYON_NUM_THREADS=$th OMP_NUM_THREADS=$th PYTHONUNBUFFERED=1 timeout 150 python3 benches/fmm_vs_fmm3d.py --sizes 200000 --digits 6 --clouds uniform > "$OUT/vs_fmm3d_$th.md" 2>&1 ); echo "vs $th rc $?"
done
