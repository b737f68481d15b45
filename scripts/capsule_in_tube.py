#!/usr/bin/env python3
"""Speed, length and width of one cell carried along a tube, frame by frame.

    python3 scripts/capsule_in_tube.py OUT

OUT is the output folder of `mobo run` on a scene with `[flow] kind = "tube"` and one cell
(examples/scenes/capsule_in_a_tube.toml). From OUT/scene.toml (the mean speed V) and the frames'
grid points it prints, per frame: the time, the mean axial position of the cell's grid points,
its axial speed over V (a difference of consecutive frames), its length along the axis
(extent of the grid points, over 2a for a cell of equivalent radius a) and its width (twice the
largest distance of a grid point from the axis). Published capsule data (Hu et al. 2012;
Lefebvre & Barthes-Biesel 2007) give U/V and L/2a against Ca and a/R.
"""
import ast
import os
import struct
import sys
import tomllib


def load_npy(path):
    """A little-endian float64 .npy file: (shape, values)."""
    with open(path, "rb") as f:
        b = f.read()
    if b[:6] != b"\x93NUMPY":
        sys.exit(f"{path}: not a .npy file")
    hl = struct.unpack("<H", b[8:10])[0]
    head = ast.literal_eval(b[10 : 10 + hl].decode())
    if head.get("descr") != "<f8":
        sys.exit(f"{path}: expected float64 data, found {head.get('descr')}")
    n = (len(b) - 10 - hl) // 8
    return head["shape"], struct.unpack(f"<{n}d", b[10 + hl :])


def mean_speed(scene):
    flow = scene.get("flow", {})
    if flow.get("kind") != "tube":
        sys.exit("the scene's [flow] is not a tube flow")
    walls = [w for w in scene.get("walls", []) if w.get("shape") == "tube"]
    if not walls:
        sys.exit("the scene has no tube wall")
    r = walls[0]["radius"]
    mu = scene.get("fluid", {}).get("viscosity", 1.0)
    if "mean_speed" in flow:
        return flow["mean_speed"]
    if "speed" in flow:
        return flow["speed"] / 2
    if "flow_rate" in flow:
        return flow["flow_rate"] / (3.141592653589793 * r * r)
    if "pressure_gradient" in flow:
        return flow["pressure_gradient"] * r * r / (8 * mu)
    sys.exit("the tube flow has no drive")


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    with open(os.path.join(out, "scene.toml"), "rb") as f:
        scene = tomllib.load(f)
    v = mean_speed(scene)
    cells = scene.get("cells", [])
    radius = cells[0].get("radius", 1.0) if cells else 1.0
    _, times = load_npy(os.path.join(out, "frames", "times.npy"))
    print(f"mean speed V = {v}, cell radius a = {radius}")
    print("| t | x | U/V | L/2a | width/2a |")
    print("|---|---|---|---|---|")
    prev = None
    for i, t in enumerate(times):
        shape, p = load_npy(os.path.join(out, "frames", f"frame_{i:05d}_positions.npy"))
        if len(shape) != 3 or shape[0] != 1 or shape[1] != 3:
            sys.exit(f"frame {i}: expected one cell's positions (1, 3, n), found {shape}")
        n = shape[2]
        xs = p[:n]
        rs = [(p[n + k] ** 2 + p[2 * n + k] ** 2) ** 0.5 for k in range(n)]
        x = sum(xs) / n
        speed = "" if prev is None else f"{(x - prev[1]) / (t - prev[0]) / v:.4f}"
        print(
            f"| {t:.2f} | {x:.4f} | {speed} | {(max(xs) - min(xs)) / (2 * radius):.4f} "
            f"| {max(rs) / radius:.4f} |"
        )
        prev = (t, x)


if __name__ == "__main__":
    main()
