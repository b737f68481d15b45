//! A planar channel: two parallel plates, closed at their edges into one rounded box, the
//! container of flow between plates.
//!
//! The flow runs along x between the plates `z = ±H`. The container's surface is the
//! superellipsoid
//!
//! ```text
//! |x/L|ⁿ + |y/W|ⁿ + |z/H|ⁿ = 1,   n = CHANNEL_EXPONENT,
//! ```
//!
//! with `2L` the length (along the flow), `2W` the width (across it) and `2H` the height (plate
//! to plate), parametrised by the sphere's angles about the x axis as
//! `X(θ, φ) = (L cos θ, W sin θ cos φ, H sin θ sin φ) / N(θ, φ)`,
//! `N = (|cos θ|ⁿ + |sin θ cos φ|ⁿ + |sin θ sin φ|ⁿ)^{1/n}`: the direction `(cos θ, sin θ cos φ,
//! sin θ sin φ)` scaled onto the box. `n` is even, so the surface is analytic and its
//! spherical-harmonic expansion converges exponentially with the order (the scaling keeps the
//! singularities of `N` a fixed distance from real angles, whatever the aspect ratio; a map
//! along rays from the centre would bring them within `H/2L` and converge slowly). In its
//! middle the surface is the two plates: `z = ±H (1 − |x/L|ⁿ − |y/W|ⁿ)^{1/n}`, within `10⁻³ H`
//! of `±H` where `|x/L|ⁿ + |y/W|ⁿ ≤ 1 − (1 − 10⁻³)ⁿ` ([`flat_fraction`]).
//!
//! A channel container carries flow: `[flow] kind = "channel"` prescribes the plane Poiseuille
//! profile `U (1 − z²/H²) e_x` on the whole wall. It is zero on the plates and the undisturbed
//! channel flow across the sides and the ends, which stand for the fluid beyond the box. The
//! profile solves the Stokes equations everywhere, so without cells it is exactly the flow
//! inside; cells disturb it, and the box keeps their disturbance inside. The sides are thus
//! the channel's truncation, as the rounded ends are a finite tube's.

use super::WallError;
use crate::vesicle::Surface;

/// The exponent `n` of the channel's superellipsoid: 6, as for the tube
/// ([`super::TUBE_END_EXPONENT`]), so that its edges are as well resolved at the same order.
pub const CHANNEL_EXPONENT: i32 = 6;

/// The spherical-harmonic surface of order `p` of a channel box of `length` `2L` (along x),
/// `width` `2W` (along y) and `height` `2H` (along z, plate to plate), centred at the origin.
///
/// # Errors
/// [`WallError::Parameter`] for an extent not positive and finite, or a length or width below
/// the height (that is not a channel between plates); a surface error for an order below 2.
pub fn channel_surface(
    p: usize,
    length: f64,
    width: f64,
    height: f64,
) -> Result<Surface, WallError> {
    for (name, value) in [
        ("channel length", length),
        ("channel width", width),
        ("channel height", height),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(WallError::Parameter {
                name,
                value,
                reason: "must be positive and finite",
            });
        }
    }
    for (name, value) in [("channel length", length), ("channel width", width)] {
        if value < height {
            return Err(WallError::Parameter {
                name,
                value,
                reason: "must be at least the height (plate to plate)",
            });
        }
    }
    let (l, w, h) = (0.5 * length, 0.5 * width, 0.5 * height);
    let n = CHANNEL_EXPONENT;
    Ok(Surface::from_fn(p, |t, f| {
        let (s, c) = t.sin_cos();
        let (sf, cf) = f.sin_cos();
        let d = [c, s * cf, s * sf];
        let norm =
            (d[0].abs().powi(n) + d[1].abs().powi(n) + d[2].abs().powi(n)).powf(1.0 / n as f64);
        [l * d[0] / norm, w * d[1] / norm, h * d[2] / norm]
    })?)
}

/// The fraction `f` of the half-length and of the half-width over which the plates are flat
/// to `tolerance · H` along the channel's centre lines: the plate's height is within the
/// tolerance of `H` at `|x| ≤ f L` (`y = 0`) and at `|y| ≤ f W` (`x = 0`),
/// `f = (1 − (1 − tolerance)ⁿ)^{1/n}` (0.43 for 10⁻³).
pub fn flat_fraction(tolerance: f64) -> f64 {
    let n = CHANNEL_EXPONENT;
    (1.0 - (1.0 - tolerance.clamp(0.0, 1.0)).powi(n)).powf(1.0 / n as f64)
}

/// The area of `|ξ|ⁿ + |η|ⁿ ≤ 1` for the channel's exponent `n = 6`, `4 Γ(1 + 1/n)² / Γ(1 + 2/n)`.
const UNIT_FLAT_AREA: f64 = 3.855_242_593_319_997;

/// The area over which each plate of a channel `length × width` (full extents) is flat to
/// `tolerance · H`: the region `|x/L|ⁿ + |y/W|ⁿ ≤ 1 − (1 − tolerance)ⁿ` (`L`, `W` the half
/// extents), `4 L W f² Γ(1 + 1/n)²/Γ(1 + 2/n)` with `f` the [`flat_fraction`].
pub fn flat_area(length: f64, width: f64, tolerance: f64) -> f64 {
    let f = flat_fraction(tolerance);
    0.25 * length * width * f * f * UNIT_FLAT_AREA
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sph_harmonics::ShTransform;

    /// The grid points lie on the superellipsoid to the order's projection error, the plates
    /// are flat in the middle, and bad extents are refused.
    #[test]
    fn channel_points_lie_on_the_box() {
        let (l, w, h) = (8.0, 6.0, 2.0);
        let s = channel_surface(32, l, w, h).unwrap();
        let sht = ShTransform::new(32).unwrap();
        let pos = s.grid_positions(&sht).unwrap();
        let np = pos.len() / 3;
        let n = CHANNEL_EXPONENT;
        let f = flat_fraction(1e-3);
        let (mut worst, mut plate, mut on_plate) = (0.0f64, 0.0f64, 0);
        for j in 0..np {
            let x = [pos[j], pos[np + j], pos[2 * np + j]];
            let g = (x[0] / (0.5 * l)).abs().powi(n)
                + (x[1] / (0.5 * w)).abs().powi(n)
                + (x[2] / (0.5 * h)).abs().powi(n);
            worst = worst.max((g - 1.0).abs());
            if x[0].abs() < 0.5 * f * 0.5 * l && x[1].abs() < 0.5 * f * 0.5 * w {
                plate = plate.max((x[2].abs() - 0.5 * h).abs() / (0.5 * h));
                on_plate += 1;
            }
        }
        assert!(on_plate > 20, "{on_plate} points on the plates' middle");
        assert!(worst < 1e-3, "off the superellipsoid by {worst:.1e}");
        assert!(plate < 1e-3, "plates off flat by {plate:.1e}");
        assert!((flat_fraction(1e-3) - 0.4261).abs() < 1e-4);
        assert!(channel_surface(8, 1.0, 4.0, 2.0).is_err());
        assert!(channel_surface(8, 4.0, 4.0, -2.0).is_err());
        assert!(channel_surface(8, 4.0, f64::NAN, 2.0).is_err());
    }

    /// The flat area against a midpoint sum over the plate's grid of the points where the
    /// surface's height is within the tolerance.
    #[test]
    fn the_flat_area_is_the_region_where_the_plate_is_flat() {
        let (l, w, tol): (f64, f64, f64) = (8.0, 6.0, 1e-3);
        let n = CHANNEL_EXPONENT;
        let m = 2000;
        let c = 1.0 - (1.0 - tol).powi(n);
        let mut count = 0usize;
        for i in 0..m {
            for j in 0..m {
                let x: f64 = (i as f64 + 0.5) / m as f64;
                let y: f64 = (j as f64 + 0.5) / m as f64;
                if x.powi(n) + y.powi(n) <= c {
                    count += 1;
                }
            }
        }
        let direct = 4.0 * (0.5 * l) * (0.5 * w) * count as f64 / (m * m) as f64;
        let a = flat_area(l, w, tol);
        assert!((a - direct).abs() < 2e-3 * a, "{a} against {direct}");
    }
}
