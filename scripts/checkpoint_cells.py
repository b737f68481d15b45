#!/usr/bin/env python3
"""Cut a `mobo run` checkpoint down to some of its cells, to reproduce a failure cheaply.

    scripts/checkpoint_cells.py IN OUT --cells 10,11

A cell run's checkpoint (format version 1, `src/io/checkpoint.rs`) keeps one row per cell in
every per-cell array (shape, tension, BDF2 history, Skalak reference and labels, ...). This
keeps the rows of the cells named (in that order), sets the header's cell count, drops the
frame times (the cut run has no frames) and resets the iteration counters. Resume it with a
scene whose cells are as many, with the same membrane parameters and numerics:

    mkdir cut && cp OUT cut/checkpoint.bin && cp my_scene.toml cut/scene.toml  # count edited
    mobo run --resume cut

The shapes, positions and histories come from the checkpoint; the scene's placement keys are
not used. docs/hard_cases.md (2026-12-05) used it to find that one cell of a 27-cell failure
failed alone. Needs numpy.
"""
import argparse
import json
import struct

import numpy as np

MAGIC = b"MOBOCKPT"


def fnv1a64(data):
    h = 0xCBF29CE484222325
    for b in data:
        h ^= b
        h = (h * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def read(path):
    b = open(path, "rb").read()
    if b[:8] != MAGIC:
        raise SystemExit(f"{path}: not a mobo checkpoint (bad magic bytes)")
    version, size = struct.unpack_from("<IQ", b, 8)
    if version != 1:
        raise SystemExit(f"{path}: format version {version}, this script reads 1")
    if size != len(b) or fnv1a64(b[:-8]) != struct.unpack_from("<Q", b, len(b) - 8)[0]:
        raise SystemExit(f"{path}: truncated or corrupt (length or checksum)")
    at = 20
    (hl,) = struct.unpack_from("<Q", b, at)
    at += 8
    meta = json.loads(b[at : at + hl])
    at += hl
    (count,) = struct.unpack_from("<Q", b, at)
    at += 8
    arrays = []
    for _ in range(count):
        (nl,) = struct.unpack_from("<I", b, at)
        at += 4
        name = b[at : at + nl].decode()
        at += nl
        (nd,) = struct.unpack_from("<I", b, at)
        at += 4
        shape = list(struct.unpack_from(f"<{nd}Q", b, at))
        at += 8 * nd
        n = int(np.prod(shape)) if shape else 1
        data = np.frombuffer(b, dtype="<f8", count=n, offset=at).copy()
        at += 8 * n
        arrays.append((name, shape, data))
    return meta, arrays


def write(path, meta, arrays):
    header = json.dumps(meta, separators=(",", ":")).encode()
    body = struct.pack("<Q", len(header)) + header + struct.pack("<Q", len(arrays))
    for name, shape, data in arrays:
        nb = name.encode()
        body += struct.pack("<I", len(nb)) + nb + struct.pack("<I", len(shape))
        body += struct.pack(f"<{len(shape)}Q", *shape) + np.asarray(data, "<f8").tobytes()
    out = MAGIC + struct.pack("<IQ", 1, 8 + 4 + 8 + len(body) + 8) + body
    out += struct.pack("<Q", fnv1a64(out))
    tmp = path + ".tmp"
    open(tmp, "wb").write(out)
    import os

    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--cells", required=True, help="comma-separated cell indices to keep")
    a = ap.parse_args()
    meta, arrays = read(a.input)
    n = meta.get("cells")
    keep = [int(x) for x in a.cells.split(",")]
    bad = [i for i in keep if not 0 <= i < n]
    if bad:
        raise SystemExit(f"{a.input}: has {n} cells, no cell {bad[0]}")
    out = []
    for name, shape, data in arrays:
        if name == "frame_times":
            shape, data = [0], np.zeros(0)
        elif shape and shape[0] == n and name not in ("clocks", "time_steps"):
            data = data.reshape(shape)[keep].ravel()
            shape = [len(keep)] + shape[1:]
        out.append((name, shape, data))
    meta["cells"] = len(keep)
    meta["iters_sum"] = 0
    meta["iters_max"] = 0
    write(a.output, meta, out)
    print(f"{a.output}: cells {keep} of {n}, step {meta.get('step')}")


if __name__ == "__main__":
    main()
