//! One rigid surface: its shape, which side the fluid is on, and its geometry on the grid.

use super::WallError;
use crate::linalg3::{cross3, dist3};
use crate::vesicle::{Geometry, Surface, SurfaceCalculus};

/// Which side of a closed surface the fluid is on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WallKind {
    /// The fluid is inside (a vessel, a closed channel, a cavity).
    Container,
    /// The fluid is outside (a rigid particle, an obstacle).
    Body,
}

/// A closed rigid surface of order `p` with its geometry on the order-`p` grid.
#[derive(Clone, Debug)]
pub struct Wall {
    kind: WallKind,
    surface: Surface,
    geometry: Geometry,
    centroid: [f64; 3],
    /// Largest distance of a grid point from the centroid.
    rmax: f64,
}

impl Wall {
    /// A wall of the given kind on `surface` (an outward-oriented spherical-harmonic surface).
    pub fn new(kind: WallKind, surface: Surface) -> Result<Self, WallError> {
        let mut calc = SurfaceCalculus::new(surface.order())?;
        let geometry = calc.geometry(surface.coefs())?;
        let centroid = geometry.centroid();
        let rmax = geometry
            .x
            .iter()
            .map(|&x| dist3(x, centroid))
            .fold(0.0, f64::max);
        Ok(Wall {
            kind,
            surface,
            geometry,
            centroid,
            rmax,
        })
    }

    /// Container or body.
    pub fn kind(&self) -> WallKind {
        self.kind
    }
    /// The surface.
    pub fn surface(&self) -> &Surface {
        &self.surface
    }
    /// The order `p`.
    pub fn order(&self) -> usize {
        self.surface.order()
    }
    /// Grid points, `2p(p+1)`.
    pub fn n_points(&self) -> usize {
        self.geometry.n_points()
    }
    /// The geometry on the order-`p` grid.
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }
    /// The centroid (the centre of a body's Stokeslet and rotlet).
    pub fn centroid(&self) -> [f64; 3] {
        self.centroid
    }
    /// Largest distance of a grid point from the centroid.
    pub fn max_radius(&self) -> f64 {
        self.rmax
    }
    /// Surface area.
    pub fn area(&self) -> f64 {
        self.geometry.area()
    }
    /// Grid positions, component-major (`3 · n_points`).
    pub fn positions(&self) -> Vec<f64> {
        let n = self.n_points();
        let mut out = vec![0.0; 3 * n];
        for (j, x) in self.geometry.x.iter().enumerate() {
            for a in 0..3 {
                out[a * n + j] = x[a];
            }
        }
        out
    }
    /// The velocity of a rigid motion `v + ω × (x − centroid)` on the grid, component-major.
    pub fn rigid_velocity(&self, v: [f64; 3], omega: [f64; 3]) -> Vec<f64> {
        let n = self.n_points();
        let mut out = vec![0.0; 3 * n];
        for (j, x) in self.geometry.x.iter().enumerate() {
            let r = [
                x[0] - self.centroid[0],
                x[1] - self.centroid[1],
                x[2] - self.centroid[2],
            ];
            let w = cross3(omega, r);
            for a in 0..3 {
                out[a * n + j] = v[a] + w[a];
            }
        }
        out
    }
}
