//! Cell shapes as spherical-harmonic surfaces, with scaling and placement.
//!
//! A [`Surface`] of order `p` holds the coefficients of `x(θ, φ)`, `y(θ, φ)`, `z(θ, φ)` (three
//! coefficient vectors of [`crate::sph_harmonics::CoefLayout`] length, one after another). The
//! constructors sample a parametrisation on the grid of order `p` and transform it; the sphere,
//! ellipsoids and spheroids are of degree 1 and the RBC of degree 5 in the parameter, so for
//! `p ≥ 5` all are represented exactly (to round-off).
//!
//! * [`sphere`], [`ellipsoid`] (semi-axes along `x, y, z`);
//! * [`rbc`]: the biconcave red blood cell of Evans & Fung (1972) as used by MOBO,
//!   `x = α sinθ cosφ, y = α sinθ sinφ, z = ½α(0.207 + 2.003 sin²θ − 1.123 sin⁴θ) cosθ` with
//!   `α = 1.3858189`, which gives equivalent radius 1 (radius of the sphere of equal volume) and
//!   reduced volume `v ≈ 0.644`;
//! * [`reduced_volume_spheroid`]: the prolate or oblate spheroid of given reduced volume
//!   `v = 6√π V / A^{3/2}` and equivalent radius, the aspect ratio found by bisection on the
//!   closed-form spheroid area;
//! * [`Surface::from_coefs`]: user-given coefficients.
//!
//! Placement: [`Surface::translate`], [`Surface::rotate`] (about the origin) and
//! [`Surface::rotate_about`] act exactly on the coefficients (`x ↦ R x + d` is linear in them);
//! [`Surface::scale_to_equivalent_radius`] scales about the centroid.

use std::f64::consts::PI;

use super::geometry::SurfaceCalculus;
use super::{check_len, VesicleError};
use crate::sph_harmonics::{resample_coefs, CoefLayout, ShTransform};

/// The RBC scale `α` of [`rbc`]: its radius when the equivalent radius is 1.
pub const RBC_ALPHA: f64 = 1.385_818_9;

/// A closed surface given by the spherical-harmonic coefficients of its three coordinates.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    p: usize,
    coefs: Vec<f64>,
}

/// Which spheroid of a given reduced volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spheroid {
    /// Elongated along `z` (semi-axes `a, a, c` with `c > a`).
    Prolate,
    /// Flattened along `z` (`c < a`).
    Oblate,
}

impl Surface {
    /// A surface from coefficients: `3 ((p+1)² − 1)` values, `x` then `y` then `z`.
    pub fn from_coefs(p: usize, coefs: Vec<f64>) -> Result<Self, VesicleError> {
        if p == 0 {
            return Err(crate::sph_harmonics::SphError::InvalidOrder(0).into());
        }
        check_len(
            "surface coefficients",
            coefs.len(),
            3 * CoefLayout::new(p).len(),
        )?;
        if coefs.iter().any(|c| !c.is_finite()) {
            return Err(VesicleError::Degenerate(
                "non-finite surface coefficient".into(),
            ));
        }
        Ok(Surface { p, coefs })
    }

    /// The surface of a parametrisation `X(θ, φ)` sampled on the grid of order `p` (exact for
    /// parametrisations of degree `≤ p`, otherwise the discrete projection).
    pub fn from_fn(p: usize, f: impl Fn(f64, f64) -> [f64; 3]) -> Result<Self, VesicleError> {
        let sht = ShTransform::new(p)?;
        let np = sht.n_points();
        let mut pos = vec![0.0; 3 * np];
        for j in 0..np {
            let (t, ph) = sht.grid().angles(j);
            let x = f(t, ph);
            for c in 0..3 {
                pos[c * np + j] = x[c];
            }
        }
        Self::from_grid(&sht, &pos)
    }

    /// The surface through grid positions (component-major, `3 · 2p(p+1)` values).
    pub fn from_grid(sht: &ShTransform, positions: &[f64]) -> Result<Self, VesicleError> {
        check_len("grid positions", positions.len(), 3 * sht.n_points())?;
        let mut coefs = vec![0.0; 3 * sht.n_coefs()];
        sht.forward(positions, &mut coefs, &mut sht.workspace())?;
        Self::from_coefs(sht.order(), coefs)
    }

    /// The order `p`.
    pub fn order(&self) -> usize {
        self.p
    }
    /// The coefficients (`x` then `y` then `z`).
    pub fn coefs(&self) -> &[f64] {
        &self.coefs
    }
    /// Mutable coefficients.
    pub fn coefs_mut(&mut self) -> &mut [f64] {
        &mut self.coefs
    }

    /// Grid positions on the grid of `sht` (its order must be `p`), component-major.
    pub fn grid_positions(&self, sht: &ShTransform) -> Result<Vec<f64>, VesicleError> {
        if sht.order() != self.p {
            return Err(VesicleError::Order {
                p: self.p,
                q: sht.order(),
            });
        }
        let mut out = vec![0.0; 3 * sht.n_points()];
        sht.inverse(&self.coefs, &mut out, &mut sht.workspace())?;
        Ok(out)
    }

    /// The same surface at order `q` (exact for `q ≥ p`, a truncation below).
    pub fn resampled(&self, q: usize) -> Result<Surface, VesicleError> {
        if q == 0 {
            return Err(crate::sph_harmonics::SphError::InvalidOrder(0).into());
        }
        let (from, to) = (CoefLayout::new(self.p), CoefLayout::new(q));
        let mut c = vec![0.0; 3 * to.len()];
        resample_coefs(&from, &to, &self.coefs, &mut c)?;
        Ok(Surface { p: q, coefs: c })
    }

    /// Translate by `d`: the constant `Y_0^0 = 1/√(4π)` gets `d √(4π)`.
    pub fn translate(&mut self, d: [f64; 3]) {
        let nc = self.coefs.len() / 3;
        let s = (4.0 * PI).sqrt();
        for (c, dc) in d.iter().enumerate() {
            self.coefs[c * nc] += dc * s;
        }
    }

    /// Rotate about the origin, `x ↦ R x`; `R` must be a proper rotation (to `1e-10`).
    pub fn rotate(&mut self, r: [[f64; 3]; 3]) -> Result<(), VesicleError> {
        check_rotation(&r)?;
        let nc = self.coefs.len() / 3;
        for i in 0..nc {
            let v = [self.coefs[i], self.coefs[nc + i], self.coefs[2 * nc + i]];
            for (a, row) in r.iter().enumerate() {
                self.coefs[a * nc + i] = row[0] * v[0] + row[1] * v[1] + row[2] * v[2];
            }
        }
        Ok(())
    }

    /// Rotate about `centre`: `x ↦ centre + R (x − centre)`.
    pub fn rotate_about(&mut self, r: [[f64; 3]; 3], centre: [f64; 3]) -> Result<(), VesicleError> {
        check_rotation(&r)?;
        self.translate([-centre[0], -centre[1], -centre[2]]);
        self.rotate(r)?;
        self.translate(centre);
        Ok(())
    }

    /// Scale about the centroid so that the equivalent radius `(3V/4π)^{1/3}` becomes `radius`.
    pub fn scale_to_equivalent_radius(&mut self, radius: f64) -> Result<(), VesicleError> {
        positive("equivalent radius", radius)?;
        let mut calc = SurfaceCalculus::new(self.p)?;
        let g = calc.geometry(&self.coefs)?;
        let c = g.centroid();
        let s = radius / g.equivalent_radius();
        self.translate([-c[0], -c[1], -c[2]]);
        self.coefs.iter_mut().for_each(|a| *a *= s);
        self.translate(c);
        Ok(())
    }

    /// Move the centroid to `centre`.
    pub fn place_centroid(&mut self, centre: [f64; 3]) -> Result<(), VesicleError> {
        let mut calc = SurfaceCalculus::new(self.p)?;
        let c = calc.geometry(&self.coefs)?.centroid();
        self.translate([centre[0] - c[0], centre[1] - c[1], centre[2] - c[2]]);
        Ok(())
    }
}

fn check_rotation(r: &[[f64; 3]; 3]) -> Result<(), VesicleError> {
    let mut err: f64 = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let rtr: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            err = err.max((rtr - want).abs());
        }
    }
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
        - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    if err > 1e-10 || (det - 1.0).abs() > 1e-10 || !err.is_finite() {
        return Err(VesicleError::NotRotation(err));
    }
    Ok(())
}

fn positive(name: &'static str, value: f64) -> Result<(), VesicleError> {
    if value > 0.0 && value.is_finite() {
        Ok(())
    } else {
        Err(VesicleError::Parameter {
            name,
            value,
            reason: "must be positive and finite",
        })
    }
}

/// The sphere of radius `radius` centred at the origin.
pub fn sphere(p: usize, radius: f64) -> Result<Surface, VesicleError> {
    positive("radius", radius)?;
    ellipsoid(p, [radius; 3])
}

/// The ellipsoid `(x/a)² + (y/b)² + (z/c)² = 1`, `axes = [a, b, c]`, centred at the origin,
/// parametrised by `X = (a sinθ cosφ, b sinθ sinφ, c cosθ)`.
pub fn ellipsoid(p: usize, axes: [f64; 3]) -> Result<Surface, VesicleError> {
    for a in axes {
        positive("ellipsoid semi-axis", a)?;
    }
    Surface::from_fn(p, |t, f| {
        let (s, c) = t.sin_cos();
        [axes[0] * s * f.cos(), axes[1] * s * f.sin(), axes[2] * c]
    })
}

/// The biconcave RBC with unit equivalent radius (axis of symmetry `z`): the Evans–Fung
/// profile `X = (α sin θ cos φ, α sin θ sin φ, (α/2)(0.207 + 2.003 sin²θ − 1.123 sin⁴θ) cos θ)`
/// (Evans & Fung, Microvasc. Res. 4, 1972), `α` = [`RBC_ALPHA`].
/// Exact for `p ≥ 5`; lower orders give its truncation.
pub fn rbc(p: usize) -> Result<Surface, VesicleError> {
    let a = RBC_ALPHA;
    Surface::from_fn(p, |t, f| {
        let (s, c) = t.sin_cos();
        let s2 = s * s;
        [
            a * s * f.cos(),
            a * s * f.sin(),
            0.5 * a * (0.207 + 2.003 * s2 - 1.123 * s2 * s2) * c,
        ]
    })
}

/// Reduced volume `6√π V / A^{3/2}` of the spheroid with semi-axes `(1, 1, t)`.
///
/// Area: prolate (`t > 1`, `e² = 1 − 1/t²`) `A = 2π(1 + t arcsin(e)/e)`; oblate (`t < 1`,
/// `e² = 1 − t²`) `A = 2π(1 + t² artanh(e)/e)`; series in `e` near the sphere.
pub fn spheroid_reduced_volume(t: f64) -> f64 {
    let area = if t >= 1.0 {
        let e2 = (1.0 - 1.0 / t) * (1.0 + 1.0 / t);
        let e = e2.sqrt();
        let ratio = if e < 1e-4 {
            1.0 + e2 / 6.0 + 3.0 * e2 * e2 / 40.0
        } else {
            e.asin() / e
        };
        2.0 * PI * (1.0 + t * ratio)
    } else {
        let e2 = (1.0 - t) * (1.0 + t);
        let e = e2.sqrt();
        let ratio = if e < 1e-4 {
            1.0 + e2 / 3.0 + e2 * e2 / 5.0
        } else {
            e.atanh() / e
        };
        2.0 * PI * (1.0 + t * t * ratio)
    };
    let vol = 4.0 / 3.0 * PI * t;
    6.0 * PI.sqrt() * vol / area.powf(1.5)
}

/// Aspect ratio `t = c/a` of the spheroid of reduced volume `v ∈ (0, 1]`, by bisection in
/// `ln t` (the reduced volume is monotone on each branch).
pub fn spheroid_aspect_ratio(v: f64, kind: Spheroid) -> Result<f64, VesicleError> {
    // ln t ∈ [0, 12] (prolate) or [−12, 0] (oblate): v reaches ~1e-5 at the far end.
    let far = match kind {
        Spheroid::Prolate => 12.0f64,
        Spheroid::Oblate => -12.0,
    };
    if !(v > spheroid_reduced_volume(far.exp()) && v <= 1.0) {
        return Err(VesicleError::Parameter {
            name: "reduced volume",
            value: v,
            reason: "must lie in (v_min, 1] with v_min ≈ 1e-5 (spheroids with aspect ≤ e^12)",
        });
    }
    let (mut lo, mut hi) = (0.0f64, far); // v(lo) ≥ v > v(hi)
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if spheroid_reduced_volume(mid.exp()) >= v {
            lo = mid;
        } else {
            hi = mid;
        }
        if (hi - lo).abs() < 1e-15 {
            break;
        }
    }
    Ok((0.5 * (lo + hi)).exp())
}

/// The spheroid (axis `z`) of reduced volume `v` and equivalent radius `radius`, centred at the
/// origin: semi-axes `a = R t^{−1/3}` (twice) and `c = R t^{2/3}` so that `a²c = R³`.
pub fn reduced_volume_spheroid(
    p: usize,
    v: f64,
    kind: Spheroid,
    radius: f64,
) -> Result<Surface, VesicleError> {
    positive("equivalent radius", radius)?;
    let t = spheroid_aspect_ratio(v, kind)?;
    let a = radius * t.powf(-1.0 / 3.0);
    let c = radius * t.powf(2.0 / 3.0);
    ellipsoid(p, [a, a, c])
}
