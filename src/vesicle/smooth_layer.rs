//! A surface's layer potentials at targets well away from it, by the smooth quadrature on the
//! surface upsampled to order `q`, with a cheap test of which targets it resolves.
//!
//! `L[f](x) ≈ Σ_i K(x − y_i, n_i) f_i dA_i` over the order-`q` grid, the density interpolated
//! spectrally from the order-`p` grid (exact: it is band-limited). The rule's error falls like
//! `exp(−2π d/h)` in the distance `d` over the spacing `h ≈ π R_max/q`; a target is
//! **resolved** when `d ≥ ratio · 2π R_max/q`, with `d` bounded from below by the bounding
//! sphere: `|x − c| − R_max` outside it, and for a target inside a container
//! `R_min − |x − c|` (`R_min`, `R_max` the smallest and largest distances of the surface from its
//! centroid `c`, taken over the order-`q` samples less one spacing). The test costs `O(1)` per
//! target where [`super::near::OffSurface`] searches the whole fine grid, so callers send it
//! the targets it resolves and the rest to [`super::near::OffSurface`].
//!
//! The bounding spheres resolve nothing inside a long container (a tube's `R_max` is its
//! half-length, beyond its radius). [`SmoothLayer::side_by_distance`] bounds `d` from below by
//! the rule's own nodes instead: the nearest node's distance less the largest distance of a
//! surface point from its nearest node (`slack`: the largest diagonal of a grid cell, or the
//! diameter of a pole's first ring, whichever is larger), and takes the side from the solid
//! angle, `O(q²)` per target: a quarter of one sum of [`super::near::OffSurface`]'s far rule at
//! `6p`, which also searches its nodes and takes the solid angle on them.

use std::f64::consts::PI;

use super::smooth_sources::SmoothSources;
use super::{check_len, Geometry, LayerKernel, SurfaceCalculus, VesicleError};
use crate::linalg3::dist3;
use crate::sph_harmonics::{resample_coefs, ShTransform, ShWorkspace};

/// A point force: where it acts and the force (a quadrature node and its weighted density).
pub type PointForce = ([f64; 3], [f64; 3]);

/// Where a target is, as far as the bounding spheres tell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Farther than `ratio · 2π R_max / q` outside the surface.
    FarOutside,
    /// Farther than that inside it.
    FarInside,
    /// Anywhere else: ask the near-zone evaluator.
    Unresolved,
}

/// The largest diagonal of a cell between two neighbouring latitudes of the points `x` on the
/// grid of order `q` (latitude-major, `2q` longitudes): a bound on the spacing of a grid however
/// a surface stretches it.
pub(crate) fn largest_cell_diagonal(x: &[[f64; 3]], q: usize) -> f64 {
    let nl = 2 * q;
    let mut s = 0.0f64;
    for i in 0..q {
        for k in 0..nl {
            let (a, b) = (i * nl + k, i * nl + (k + 1) % nl);
            s = s.max(dist3(x[a], x[b + nl])).max(dist3(x[b], x[a + nl]));
        }
    }
    s
}

/// The largest distance of a surface point from its nearest node, bounded by the grid of
/// order `q`: the [`largest_cell_diagonal`], and the diameter of the first and last latitude
/// (the caps around the poles).
pub(crate) fn node_slack(x: &[[f64; 3]], q: usize) -> f64 {
    let nl = 2 * q;
    let mut s = largest_cell_diagonal(x, q);
    for ring in [0, q] {
        for k in 0..nl / 2 {
            s = s.max(dist3(x[ring * nl + k], x[ring * nl + k + nl / 2]));
        }
    }
    s
}

/// The smooth quadrature of one surface of order `p` at order `q`.
pub struct SmoothLayer {
    p: usize,
    sht_p: ShTransform,
    ws_p: ShWorkspace,
    sht_q: ShTransform,
    ws_q: ShWorkspace,
    calc_q: SurfaceCalculus,
    geom: Geometry,
    coefs_q: Vec<f64>,
    dens_coef: Vec<f64>,
    dens_coef_q: Vec<f64>,
    dens: Vec<f64>,
    /// The nodes and the density as a block of sources.
    src: SmoothSources,
    centre: [f64; 3],
    r_min: f64,
    r_max: f64,
    /// `ratio · 2π R_max / q`.
    resolved: f64,
    /// Largest distance of a surface point from its nearest node (bound).
    slack: f64,
    ratio: f64,
    has_surface: bool,
}

impl SmoothLayer {
    /// The rule of order `q ≥ p` for surfaces of order `p`; `ratio` sets the distance it
    /// resolves (with `q = 3p`, 3 gives about 1e-10 relative error on an RBC; see the test).
    pub fn new(p: usize, q: usize, ratio: f64) -> Result<Self, VesicleError> {
        if q < p {
            return Err(VesicleError::Parameter {
                name: "smooth quadrature order",
                value: q as f64,
                reason: "must be at least the surface order",
            });
        }
        if !(ratio.is_finite() && ratio > 0.0) {
            return Err(VesicleError::Parameter {
                name: "resolve ratio",
                value: ratio,
                reason: "must be positive and finite",
            });
        }
        let sht_p = ShTransform::new(p)?;
        let sht_q = ShTransform::new(q)?;
        Ok(SmoothLayer {
            p,
            ws_p: sht_p.workspace(),
            ws_q: sht_q.workspace(),
            calc_q: SurfaceCalculus::new(q)?,
            geom: Geometry::zeros(q),
            coefs_q: vec![0.0; 3 * sht_q.n_coefs()],
            dens_coef: vec![0.0; 3 * sht_p.n_coefs()],
            dens_coef_q: vec![0.0; 3 * sht_q.n_coefs()],
            dens: vec![0.0; 3 * sht_q.n_points()],
            src: SmoothSources::new(),
            sht_p,
            sht_q,
            centre: [0.0; 3],
            r_min: 0.0,
            r_max: 0.0,
            resolved: f64::INFINITY,
            slack: f64::INFINITY,
            ratio,
            has_surface: false,
        })
    }

    /// Set the surface (order-`p` coefficients).
    pub fn set_surface(&mut self, coefs: &[f64]) -> Result<(), VesicleError> {
        check_len(
            "surface coefficients",
            coefs.len(),
            3 * self.sht_p.n_coefs(),
        )?;
        self.has_surface = false;
        resample_coefs(
            self.sht_p.layout(),
            self.sht_q.layout(),
            coefs,
            &mut self.coefs_q,
        )?;
        self.calc_q.update_geometry(&self.coefs_q, &mut self.geom)?;
        self.src.set_geometry(&self.geom);
        let c = self.geom.centroid();
        let (mut lo, mut hi) = (f64::INFINITY, 0.0_f64);
        for x in &self.geom.x {
            let r = ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2)).sqrt();
            lo = lo.min(r);
            hi = hi.max(r);
        }
        let q = self.sht_q.order() as f64;
        // Samples miss the surface's extremes by at most about a spacing.
        let spacing = PI * hi / q;
        self.centre = c;
        self.r_min = (lo - spacing).max(0.0);
        self.r_max = hi + spacing;
        self.resolved = self.ratio * 2.0 * PI * self.r_max / q;
        self.slack = node_slack(&self.geom.x, self.sht_q.order());
        self.has_surface = true;
        Ok(())
    }

    /// Where `x` is, from the distance to the rule's nearest node less the slack (a lower
    /// bound on the distance to the surface) and, where that resolves it, the solid angle
    /// `(1/4π) ∫ (y − x)·n/|y − x|³ dA` (inside above ½). Costs `O(q²)`; for the targets
    /// [`Self::side`] leaves unresolved.
    pub fn side_by_distance(&self, x: [f64; 3]) -> Side {
        if !self.has_surface {
            return Side::Unresolved;
        }
        let (d2, _) = self.src.nearest(x);
        if d2.sqrt() - self.slack < self.resolved {
            Side::Unresolved
        } else if self.src.solid_angle(x) > 0.5 {
            Side::FarInside
        } else {
            Side::FarOutside
        }
    }

    /// Where `x` is, from the bounding spheres.
    pub fn side(&self, x: [f64; 3]) -> Side {
        let c = self.centre;
        let r = ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2)).sqrt();
        if r - self.r_max >= self.resolved {
            Side::FarOutside
        } else if self.r_min - r >= self.resolved {
            Side::FarInside
        } else {
            Side::Unresolved
        }
    }

    /// Set the density (component-major on the order-`p` grid).
    pub fn set_density(&mut self, density: &[f64]) -> Result<(), VesicleError> {
        check_len("density", density.len(), 3 * self.sht_p.n_points())?;
        self.sht_p
            .forward(density, &mut self.dens_coef, &mut self.ws_p)?;
        resample_coefs(
            self.sht_p.layout(),
            self.sht_q.layout(),
            &self.dens_coef,
            &mut self.dens_coef_q,
        )?;
        self.sht_q
            .inverse(&self.dens_coef_q, &mut self.dens, &mut self.ws_q)?;
        self.src.set_density(&self.dens)?;
        Ok(())
    }

    /// Add the layer potential of the density set at `targets` to `out` (component-major,
    /// `3 · targets.len()`). The caller sends only targets [`Self::side`] resolves.
    pub fn add_to(
        &self,
        kernel: LayerKernel,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        if !self.has_surface {
            return Err(VesicleError::Parameter {
                name: "surface",
                value: f64::NAN,
                reason: "set_surface must come first",
            });
        }
        kernel.check()?;
        let nt = targets.len();
        check_len("output", out.len(), 3 * nt)?;
        let mut u = vec![0.0; 3 * nt];
        self.src.add_to(kernel, targets, &mut u)?;
        for t in 0..nt {
            for a in 0..3 {
                out[a * nt + t] += u[3 * t + a];
            }
        }
        Ok(())
    }

    /// The rule's nodes and the density set there times each node's weight: the point forces
    /// `(y_i, f_i dA_i)` whose sum [`Self::add_to`] takes for the single layer, for kernels it
    /// does not know (the images of a plane wall, [`crate::wall::PlaneWall`]).
    pub fn weighted_points(&self) -> Result<Vec<PointForce>, VesicleError> {
        if !self.has_surface {
            return Err(VesicleError::Parameter {
                name: "surface",
                value: f64::NAN,
                reason: "set_surface must come first",
            });
        }
        let nq = self.geom.n_points();
        Ok((0..nq)
            .map(|i| {
                let w = self.geom.da[i];
                (
                    self.geom.x[i],
                    [
                        self.dens[i] * w,
                        self.dens[nq + i] * w,
                        self.dens[2 * nq + i] * w,
                    ],
                )
            })
            .collect())
    }

    /// The outward unit normals at the rule's nodes (in the order of
    /// [`Self::weighted_points`]; those of the last surface set).
    pub fn normals(&self) -> &[[f64; 3]] {
        &self.geom.normal
    }

    /// The surface order `p`.
    pub fn order(&self) -> usize {
        self.p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::{shapes, NearParams, OffSurface};

    /// At the targets it resolves, the order-3p rule agrees with the near-zone evaluator (its
    /// order-6p rule) to 1e-8 of the field (4.9e-9 measured), for both kernels, outside an RBC. (Measured on
    /// the RBC's double layer at p = 8, against the distance over `2π R_max/q`: at `q = 2p`
    /// 3e-5 at 1.5, 5e-7 at 2.3, 1.6e-8 at 3.1, a floor of 2.5e-9 beyond; at `q = 3p` 3.4e-5 at
    /// 1.2, 8e-9 at 2.4, 7e-12 at 3.7; at `q = 4p` 3e-7 at 1.7, 2e-12 at 3.4.)
    /// An RBC of order `p` with the density `density(i)` at its grid values: its order-3p
    /// rule and its near-zone evaluator.
    fn rbc_rules(p: usize, density: impl Fn(usize) -> f64) -> (SmoothLayer, OffSurface, Vec<f64>) {
        let rbc = shapes::rbc(p).unwrap();
        let n = 2 * p * (p + 1);
        let dens: Vec<f64> = (0..3 * n).map(density).collect();
        let mut smooth = SmoothLayer::new(p, 3 * p, 3.0).unwrap();
        smooth.set_surface(rbc.coefs()).unwrap();
        smooth.set_density(&dens).unwrap();
        let mut near = OffSurface::new(p, NearParams::default()).unwrap();
        near.set_surface(rbc.coefs()).unwrap();
        (smooth, near, dens)
    }

    /// Both kernels by the order-3p rule and by the near-zone evaluator agree at `targets` to
    /// 1e-8 of the field.
    fn assert_rules_agree(
        smooth: &SmoothLayer,
        near: &mut OffSurface,
        dens: &[f64],
        targets: &[[f64; 3]],
        what: &str,
    ) {
        for kernel in [
            LayerKernel::SingleLayer { viscosity: 1.3 },
            LayerKernel::DoubleLayer,
        ] {
            let mut a = vec![0.0; 3 * targets.len()];
            smooth.add_to(kernel, targets, &mut a).unwrap();
            let mut b = vec![0.0; 3 * targets.len()];
            near.evaluate(kernel, dens, targets, &mut b).unwrap();
            crate::check::assert_close(what, &a, &b, 1e-8);
        }
    }

    #[test]
    fn resolved_targets_agree_with_the_off_surface_evaluator() {
        let p = 8;
        let (smooth, mut near, dens) = rbc_rules(p, |i| ((i * 37) % 11) as f64 / 11.0 - 0.4);
        let targets: Vec<[f64; 3]> = (0..40)
            .map(|k| {
                let t = k as f64 * 0.7;
                let r = 3.0 + 0.2 * k as f64;
                [r * t.cos(), r * t.sin(), 0.3 * (k as f64 - 20.0)]
            })
            .collect();
        assert!(targets.iter().all(|&x| smooth.side(x) == Side::FarOutside));
        assert_eq!(smooth.side([0.0, 0.0, 0.0]), Side::Unresolved);
        assert_rules_agree(&smooth, &mut near, &dens, &targets, "smooth order-3p rule");
        // Inside a sphere: targets near its centre are resolved from inside (at q = 4p, those
        // within 1.3 of the centre of a sphere of radius 5).
        let s = shapes::sphere(p, 5.0).unwrap();
        let mut smooth = SmoothLayer::new(p, 4 * p, 3.0).unwrap();
        smooth.set_surface(s.coefs()).unwrap();
        assert_eq!(smooth.side([0.5, 0.2, 0.0]), Side::FarInside);
        assert_eq!(smooth.side([4.9, 0.0, 0.0]), Side::Unresolved);
    }

    /// Above and below a red cell's flat faces, within its bounding sphere's unresolved shell,
    /// the points whose distance from the order-3p nodes resolves them (how a cell's layers
    /// reach a wall beside it) get the near-zone evaluator's value to 1e-8 of the field.
    #[test]
    fn points_off_a_red_cells_faces_resolved_by_the_nodes_agree_with_the_near_zone() {
        let (smooth, mut near, dens) = rbc_rules(8, |i| ((i * 29) % 13) as f64 / 13.0 - 0.45);
        let mut targets = vec![];
        for i in 0..5 {
            for j in 0..5 {
                for z in [-2.0, -1.6, -1.2, 1.2, 1.6, 2.0] {
                    targets.push([0.5 * i as f64 - 1.0, 0.5 * j as f64 - 1.0, z]);
                }
            }
        }
        assert!(targets.iter().all(|&x| smooth.side(x) == Side::Unresolved));
        let far: Vec<[f64; 3]> = targets
            .iter()
            .copied()
            .filter(|&x| smooth.side_by_distance(x) == Side::FarOutside)
            .collect();
        assert!(
            4 * far.len() > targets.len() && far.len() < targets.len(),
            "{} of {} resolved by the nodes",
            far.len(),
            targets.len()
        );
        assert_rules_agree(
            &smooth,
            &mut near,
            &dens,
            &far,
            "order-3p rule off the faces",
        );
    }
}
