//! A straight circular tube with rounded ends: the container of flow through a vessel.
//!
//! The tube's axis is the x axis. Its surface is the superellipsoid of revolution
//!
//! ```text
//! |x/L|ⁿ + (r/R)ⁿ = 1,   r² = y² + z²,   n = TUBE_END_EXPONENT,
//! ```
//!
//! with `R` the radius and `2L` the length end to end, parametrised by the sphere's angles as
//! `X(θ, φ) = (L cos θ, R sin θ cos φ, R sin θ sin φ) / N(θ)`, `N = (|sin θ|ⁿ + |cos θ|ⁿ)^{1/n}`.
//! The surface is analytic (`n` even), so its spherical-harmonic expansion converges
//! exponentially with the order; along most of its length it is the cylinder `r = R`, and it
//! closes smoothly at `x = ±L`. Its radius is `R (1 − |x/L|ⁿ)^{1/n}`: [`straight_length`] says
//! how much of the tube is within a given tolerance of `R`.
//!
//! A tube container carries flow: `[flow] kind = "tube"` prescribes Poiseuille's profile
//! `U (1 − r²/R²)` on the whole wall, which is zero on the straight side and the inflow and
//! outflow profile across the rounded ends. Poiseuille's flow then solves the problem exactly
//! inside, and `tests/walls.rs` measures how closely the solver keeps it.

use super::WallError;
use crate::vesicle::Surface;

/// The exponent `n` of the tube's superellipsoid. 6: the radius is within 10⁻³ of `R` over the
/// middle 43 % of the length and within 10⁻⁴ over the middle 29 %; a tube 6 radii long keeps
/// Poiseuille's flow to 2·10⁻⁵ at order 32 and 10⁻⁷ at order 48 (8 straightens the side but
/// needs higher orders for the sharper ends: 6·10⁻⁴ at order 24 against 2·10⁻⁴; see
/// `docs/walls.md`).
pub const TUBE_END_EXPONENT: i32 = 6;

/// The spherical-harmonic surface of order `p` of a tube of `radius` `R` and `length` `2L`
/// (end to end) along the x axis, centred at the origin.
///
/// # Errors
/// [`WallError::Parameter`] for a radius or length not positive and finite, or a length
/// below two radii (that is not a tube); a surface error for an order below 2.
pub fn tube_surface(p: usize, radius: f64, length: f64) -> Result<Surface, WallError> {
    if !(radius.is_finite() && radius > 0.0) {
        return Err(WallError::Parameter {
            name: "tube radius",
            value: radius,
            reason: "must be positive and finite",
        });
    }
    if !(length.is_finite() && length >= 2.0 * radius) {
        return Err(WallError::Parameter {
            name: "tube length",
            value: length,
            reason: "must be finite and at least twice the radius",
        });
    }
    let half = 0.5 * length;
    let n = TUBE_END_EXPONENT;
    Ok(Surface::from_fn(p, |t, f| {
        let (s, c) = t.sin_cos();
        let norm = (s.abs().powi(n) + c.abs().powi(n)).powf(1.0 / n as f64);
        [
            half * c / norm,
            radius * s * f.cos() / norm,
            radius * s * f.sin() / norm,
        ]
    })?)
}

/// The length `2x` of the middle section of a tube of `length` `2L` over which its radius is
/// within `tolerance · R` of `R`: `x = L (1 − (1 − tolerance)ⁿ)^{1/n}`.
pub fn straight_length(length: f64, tolerance: f64) -> f64 {
    let n = TUBE_END_EXPONENT;
    length * (1.0 - (1.0 - tolerance.clamp(0.0, 1.0)).powi(n)).powf(1.0 / n as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sph_harmonics::ShTransform;

    /// The grid points of the surface lie on the superellipsoid, to the order's projection
    /// error, and the middle section is the cylinder.
    #[test]
    fn tube_points_lie_on_the_superellipsoid() {
        let (r, len) = (1.5, 9.0);
        let s = tube_surface(32, r, len).unwrap();
        let sht = ShTransform::new(32).unwrap();
        let pos = s.grid_positions(&sht).unwrap();
        let np = pos.len() / 3;
        let n = TUBE_END_EXPONENT;
        let (mut worst, mut middle) = (0.0f64, 0.0f64);
        let mid = 0.5 * straight_length(len, 1e-4);
        for j in 0..np {
            let (x, y, z) = (pos[j], pos[np + j], pos[2 * np + j]);
            let rr = (y * y + z * z).sqrt();
            let f = (x / (0.5 * len)).abs().powi(n) + (rr / r).powi(n);
            worst = worst.max((f - 1.0).abs());
            if x.abs() < mid {
                middle = middle.max((rr - r).abs() / r);
            }
        }
        assert!(worst < 1e-3, "off the superellipsoid by {worst:.1e}");
        assert!(middle < 2e-4, "middle radius off by {middle:.1e}");
        assert!(tube_surface(8, 1.0, 1.5).is_err());
        assert!(tube_surface(8, -1.0, 4.0).is_err());
    }
}
