#!/usr/bin/env python3
"""Write a wall for `[[walls]] shape = "grid"`: its points on mobo's spherical grid, and the
velocity it carries there (docs/walls.md, "Walls of your own shape").

The grid of order p has p + 1 latitudes theta_i = arccos(x_i), x_i the Gauss-Legendre nodes in
decreasing order (theta increasing from the pole at +z of the parameter sphere), and 2p
longitudes phi_k = k pi / p. A file holds a float64 array of shape (p + 1, 2p, 3): the point
(or velocity) at (theta_i, phi_k), x y z. The normals X_theta x X_phi must point out of the
enclosed volume (as for the unit sphere (sin t cos f, sin t sin f, cos t)).

This script writes a stenosed vessel: the tube of mobo's built-in `shape = "tube"` (the
superellipsoid of revolution |x/L|^n + (r/R)^n = 1, n = 6, along x, rounded ends) narrowed
by a Gaussian constriction r -> r (1 - depth exp(-x^2/width^2)), and the velocity that drives
Poiseuille's flow through it: U (1 - r0^2/R^2) along x at every wall point, r0 the
unconstricted tube's radius there (zero on the straight side and on the constriction, the
inflow and outflow profiles across the rounded ends: the boundary data of the built-in tube
flow, whose net flux is zero).

    python3 scripts/grid_wall.py OUT_PREFIX [--order 40] [--radius 1.8] [--length 16]
        [--depth 0.25] [--width 3.0] [--speed 1.0]

writes OUT_PREFIX.npy (positions) and OUT_PREFIX_velocity.npy. With --depth 0 it is the
built-in tube and its tube flow, point for point.
"""
import argparse

import numpy as np

TUBE_END_EXPONENT = 6


def grid(p):
    """The latitudes theta_i (increasing) and longitudes phi_k of mobo's grid of order p."""
    x, _ = np.polynomial.legendre.leggauss(p + 1)
    theta = np.arccos(x[::-1])
    phi = np.arange(2 * p) * np.pi / p
    return theta, phi


def main():
    a = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    a.add_argument("out")
    a.add_argument("--order", type=int, default=40)
    a.add_argument("--radius", type=float, default=1.8)
    a.add_argument("--length", type=float, default=16.0)
    a.add_argument("--depth", type=float, default=0.25)
    a.add_argument("--width", type=float, default=3.0)
    a.add_argument("--speed", type=float, default=1.0, help="centreline speed U")
    o = a.parse_args()
    if not (0.0 <= o.depth < 1.0):
        raise SystemExit("--depth must be in [0, 1)")
    theta, phi = grid(o.order)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    s, c = np.sin(t), np.cos(t)
    n = TUBE_END_EXPONENT
    norm = (np.abs(s) ** n + np.abs(c) ** n) ** (1.0 / n)
    x = 0.5 * o.length * c / norm
    r0 = o.radius * s / norm
    r = r0 * (1.0 - o.depth * np.exp(-((x / o.width) ** 2)))
    points = np.stack([x, r * np.cos(f), r * np.sin(f)], axis=-1)
    u = o.speed * (1.0 - (r0 / o.radius) ** 2)
    velocity = np.stack([u, 0.0 * u, 0.0 * u], axis=-1)
    np.save(f"{o.out}.npy", points.astype(np.float64))
    np.save(f"{o.out}_velocity.npy", velocity.astype(np.float64))
    print(
        f"{o.out}.npy, {o.out}_velocity.npy: order {o.order}, radius {o.radius}, length "
        f"{o.length}, throat radius {o.radius * (1 - o.depth):.4f} (depth {o.depth}, width "
        f"{o.width}), centreline speed {o.speed}"
    )


if __name__ == "__main__":
    main()
