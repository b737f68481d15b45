#!/usr/bin/env python3
"""Draw a velocity plane of `mobo run` ([output] velocity_plane) as a PNG, with numpy alone.

    python3 scripts/plane_png.py OUT_DIR FRAME picture.png [--component x|y|z|speed] [--scale K]

Colour: the chosen velocity component (default: speed) on a blue-white-red scale from its
0.1 to its 99.9 percentile in the frame (values beyond are clipped); grey where the plane leaves the fluid (NaN, a
wall or beyond it). Black: the cells' grid points within half a grid spacing of the plane (their
cross-section). Each plane point becomes a K x K block of pixels (default 6).
"""
import struct
import sys
import zlib

import numpy as np


def png(path, rgb):
    """Write an (h, w, 3) uint8 array as an 8-bit RGB PNG."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[i].tobytes() for i in range(h))

    def chunk(kind, data):
        c = kind + data
        return struct.pack(">I", len(data)) + c + struct.pack(">I", zlib.crc32(c) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 9)))
        f.write(chunk(b"IEND", b""))


def colour(t):
    """Blue (0) - white (0.5) - red (1)."""
    t = np.clip(t, 0.0, 1.0)[..., None]
    blue, white, red = np.array([33, 102, 172]), np.array([247, 247, 247]), np.array([178, 24, 43])
    lo = blue + (white - blue) * (t / 0.5)
    hi = white + (red - white) * ((t - 0.5) / 0.5)
    return np.where(t < 0.5, lo, hi)


def main(argv):
    if len(argv) < 4:
        sys.exit(__doc__)
    out, frame, target = argv[1], int(argv[2]), argv[3]
    comp = argv[argv.index("--component") + 1] if "--component" in argv else "speed"
    k = int(argv[argv.index("--scale") + 1]) if "--scale" in argv else 6
    pts = np.load(f"{out}/frames/plane_points.npy")
    vel = np.load(f"{out}/frames/frame_{frame:05d}_plane_velocity.npy")
    value = np.linalg.norm(vel, axis=2) if comp == "speed" else vel[..., "xyz".index(comp)]
    good = np.isfinite(value)
    # The 0.1 and 99.9 percentiles, so that a stray point (a near-zone failure where two
    # membrane sheets come closer than the evaluator's zone) does not wash out the picture.
    lo, hi = np.nanpercentile(value, [0.1, 99.9])
    img = colour((value - lo) / (hi - lo if hi > lo else 1.0))
    img[~good] = [200, 200, 200]
    # The cells' grid points close to the plane.
    nv, nu, _ = pts.shape
    o, eu, ev = pts[0, 0], pts[0, -1] - pts[0, 0], pts[-1, 0] - pts[0, 0]
    normal = np.cross(eu, ev)
    normal /= np.linalg.norm(normal)
    h = min(np.linalg.norm(eu) / (nu - 1), np.linalg.norm(ev) / (nv - 1))
    cells = np.load(f"{out}/frames/frame_{frame:05d}_positions.npy")  # (cells, 3, n)
    big = np.repeat(np.repeat(img, k, axis=0), k, axis=1).astype(np.uint8)
    g = np.linalg.inv(np.array([eu, ev, normal]).T)
    for c in cells:
        x = c.T - o
        a, b, d = g @ x.T
        near = np.abs(d) < 0.5 * h
        for i, j in zip(a[near] * (nu - 1) * k, b[near] * (nv - 1) * k):
            i, j = int(round(i)), int(round(j))
            if 0 <= j < big.shape[0] and 0 <= i < big.shape[1]:
                big[max(j - 1, 0):j + 2, max(i - 1, 0):i + 2] = 0
    png(target, big[::-1])  # v upwards
    print(f"{target}: {comp} from {lo:.4g} (blue) to {hi:.4g} (red), {nu} x {nv} points")


if __name__ == "__main__":
    main(sys.argv)
