//! Tank-treading of a membrane: the mean rate at which its material turns about an axis.
//!
//! A cell tank-treading in shear keeps its shape and orientation while its membrane circulates
//! around it. Its frequency is that of the material points: a point at `r = x − c` from the
//! membrane's centre turns about the axis `a` (the vorticity direction) with the phase rate
//!
//! ```text
//!     φ̇ = ((r × (u − U)) · a) / |r_⊥|²,    r_⊥ = r − (r·a) a,
//! ```
//!
//! `u` its velocity and `U` the membrane's mean velocity. The *membrane phase rate* is the
//! area-weighted mean of `φ̇` over the membrane, `ω = Σ w φ̇ / Σ w`. For a steady tank-treading
//! membrane whose material points share one period `T` (the ellipsoidal membrane of Keller &
//! Skalak, *J. Fluid Mech.* 120, 1982) it is `2π/T`: the material on an orbit is spread as the
//! inverse of its speed, so the instant mean over it equals the mean over one period. For a
//! rigid body it is the angular velocity (a sphere in the shear `u = (γ̇y, 0, 0)`: `γ̇/2`
//! clockwise about `z`). Weighted by area, it weights material evenly on a locally
//! inextensible membrane.
//!
//! Two estimates: [`phase_rate`] from velocities (the boundary-integral cells, whose grid points
//! are not material points but carry the material velocity), and [`phase_advance`] from two
//! snapshots of the same material points (DPD membrane vertices, whose thermal velocities would
//! swamp an instant estimate; their displacement over an interval averages the noise).
//! Points on the axis (`|r_⊥|` below `1e-9` of the largest) are left out of both.

use crate::linalg3::{cross3, dot3, sub3};

/// The membrane phase rate `Σ w φ̇ / Σ w` about the unit direction of `axis` (module docs),
/// positive counter-clockwise about `axis`; `c` and `U` are the `w`-weighted means of `points`
/// and `velocities`. NaN for empty input or zero weights.
///
/// ```
/// use mobo::vesicle::tank_treading::phase_rate;
/// // A ring turning rigidly at 0.5 clockwise about z (the sense of the shear u = (y, 0, 0)).
/// let pts: Vec<[f64; 3]> = (0..8)
///     .map(|k| (k as f64 * std::f64::consts::FRAC_PI_4).sin_cos())
///     .map(|(s, c)| [c, s, 0.1])
///     .collect();
/// let vel: Vec<[f64; 3]> = pts.iter().map(|p| [0.5 * p[1], -0.5 * p[0], 0.0]).collect();
/// let w = vec![1.0; 8];
/// assert!((phase_rate(&pts, &vel, &w, [0.0, 0.0, -1.0]) - 0.5).abs() < 1e-14);
/// ```
pub fn phase_rate(
    points: &[[f64; 3]],
    velocities: &[[f64; 3]],
    weights: &[f64],
    axis: [f64; 3],
) -> f64 {
    let a = unit(axis);
    let c = weighted_mean(points, weights);
    let u0 = weighted_mean(velocities, weights);
    let floor = axis_floor(points, c, a);
    let (mut sum, mut wsum) = (0.0, 0.0);
    for ((x, u), &w) in points.iter().zip(velocities).zip(weights) {
        let r = perp(sub3(*x, c), a);
        let r2 = dot3(r, r);
        if r2 <= floor {
            continue;
        }
        sum += w * dot3(cross3(r, sub3(*u, u0)), a) / r2;
        wsum += w;
    }
    sum / wsum
}

/// The mean phase advance (radians, in `(−π, π]` per point) of the same material points
/// between the snapshots `before` and `after`, about the unit direction of `axis`,
/// counter-clockwise positive: each point's angle from `r_⊥` before to `r_⊥` after, about the
/// snapshot's own `w`-weighted centre, averaged with the weights `w`. Divided by the time
/// between the snapshots, an estimate of the [`phase_rate`] over the interval; the interval
/// must be short enough that no point turns by more than `π`. NaN for empty input or zero
/// weights.
pub fn phase_advance(
    before: &[[f64; 3]],
    after: &[[f64; 3]],
    weights: &[f64],
    axis: [f64; 3],
) -> f64 {
    let a = unit(axis);
    let (c0, c1) = (
        weighted_mean(before, weights),
        weighted_mean(after, weights),
    );
    let floor = axis_floor(before, c0, a).max(axis_floor(after, c1, a));
    let (mut sum, mut wsum) = (0.0, 0.0);
    for ((x0, x1), &w) in before.iter().zip(after).zip(weights) {
        let (r0, r1) = (perp(sub3(*x0, c0), a), perp(sub3(*x1, c1), a));
        if dot3(r0, r0) <= floor || dot3(r1, r1) <= floor {
            continue;
        }
        sum += w * dot3(cross3(r0, r1), a).atan2(dot3(r0, r1));
        wsum += w;
    }
    sum / wsum
}

/// `|r_⊥|²` below which a point counts as on the axis: `1e-18` of the largest (`|r_⊥|` below
/// `1e-9` of the largest).
fn axis_floor(points: &[[f64; 3]], c: [f64; 3], a: [f64; 3]) -> f64 {
    let max = points
        .iter()
        .map(|x| {
            let r = perp(sub3(*x, c), a);
            dot3(r, r)
        })
        .fold(0.0, f64::max);
    1e-18 * max
}

fn weighted_mean(v: &[[f64; 3]], w: &[f64]) -> [f64; 3] {
    let mut m = [0.0; 3];
    let mut total = 0.0;
    for (x, &wk) in v.iter().zip(w) {
        for d in 0..3 {
            m[d] += wk * x[d];
        }
        total += wk;
    }
    m.map(|s| s / total)
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = dot3(a, a).sqrt();
    a.map(|v| v / n)
}

fn perp(r: [f64; 3], a: [f64; 3]) -> [f64; 3] {
    let s = dot3(r, a);
    [r[0] - s * a[0], r[1] - s * a[1], r[2] - s * a[2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rotation by `angle` about the unit axis `a` (Rodrigues).
    fn rotate(x: [f64; 3], a: [f64; 3], angle: f64) -> [f64; 3] {
        let (s, c) = angle.sin_cos();
        let axr = cross3(a, x);
        let ad = dot3(a, x);
        [0, 1, 2].map(|k| x[k] * c + axr[k] * s + a[k] * ad * (1.0 - c))
    }

    /// Points of a lumpy closed surface (not symmetric about any axis), with uneven weights.
    fn cloud() -> (Vec<[f64; 3]>, Vec<f64>) {
        let mut pts = Vec::new();
        let mut w = Vec::new();
        for i in 0..9 {
            let t = (i as f64 + 0.5) * std::f64::consts::PI / 9.0;
            for j in 0..13 {
                let f = j as f64 * 2.0 * std::f64::consts::PI / 13.0;
                let r = 1.0 + 0.2 * (2.0 * t).cos() * f.sin() + 0.1 * (3.0 * f).cos();
                pts.push([
                    1.3 * r * t.sin() * f.cos() + 0.4,
                    r * t.sin() * f.sin() - 0.2,
                    0.7 * r * t.cos() + 1.1,
                ]);
                w.push(t.sin() * (1.0 + 0.3 * f.cos()));
            }
        }
        (pts, w)
    }

    #[test]
    fn a_rigid_rotation_with_translation_advances_every_point_by_its_angle() {
        let (pts, w) = cloud();
        let a = unit([0.3, -1.0, 0.4]);
        for angle in [0.37, -1.2, 3.0] {
            let shift = [0.5, -2.0, 0.25];
            let after: Vec<[f64; 3]> = pts
                .iter()
                .map(|&x| {
                    let y = rotate(x, a, angle);
                    [y[0] + shift[0], y[1] + shift[1], y[2] + shift[2]]
                })
                .collect();
            let adv = phase_advance(&pts, &after, &w, a);
            assert!((adv - angle).abs() < 1e-12, "{adv} vs {angle}");
            // About the opposite axis, the opposite sense.
            let back = phase_advance(&pts, &after, &w, a.map(|v| -v));
            assert!((back + angle).abs() < 1e-12);
        }
    }

    #[test]
    fn the_rate_of_a_rigid_rotation_plus_a_translation_is_its_angular_velocity() {
        let (pts, w) = cloud();
        let a = unit([0.2, 0.5, -1.0]);
        let omega = 0.73;
        let drift = [0.3, 0.1, -0.4];
        let c = weighted_mean(&pts, &w);
        let vel: Vec<[f64; 3]> = pts
            .iter()
            .map(|&x| {
                let v = cross3(a.map(|k| omega * k), sub3(x, c));
                [v[0] + drift[0], v[1] + drift[1], v[2] + drift[2]]
            })
            .collect();
        assert!((phase_rate(&pts, &vel, &w, a) - omega).abs() < 1e-13);
        // The rate is the limit of the advance over a short interval.
        let h = 1e-6;
        let after: Vec<[f64; 3]> = pts.iter().map(|&x| rotate(x, a, omega * h)).collect();
        assert!((phase_advance(&pts, &after, &w, a) / h - omega).abs() < 1e-6);
    }

    #[test]
    fn a_pure_strain_about_the_centre_averages_to_no_turning_on_a_symmetric_ring() {
        // u = (x, −y, 0) on a ring: each point turns (φ̇ = −sin 2φ), the ring as a whole not.
        let pts: Vec<[f64; 3]> = (0..16)
            .map(|k| (k as f64 * std::f64::consts::PI / 8.0).sin_cos())
            .map(|(s, c)| [c, s, 0.0])
            .collect();
        let vel: Vec<[f64; 3]> = pts.iter().map(|p| [p[0], -p[1], 0.0]).collect();
        let w = vec![1.0; pts.len()];
        assert!(phase_rate(&pts, &vel, &w, [0.0, 0.0, 1.0]).abs() < 1e-14);
    }

    #[test]
    fn points_on_the_axis_are_left_out() {
        // ±e_x, ±e_y, ±e_z: centre at the origin, the last two on the axis (their angle 0/0).
        let pts: Vec<[f64; 3]> = (0..6)
            .map(|k| {
                let mut v = [0.0; 3];
                v[k / 2] = if k % 2 == 0 { 1.0 } else { -1.0 };
                v
            })
            .collect();
        let w = vec![1.0; pts.len()];
        let c = weighted_mean(&pts, &w);
        let after: Vec<[f64; 3]> = pts
            .iter()
            .map(|&x| {
                let r = rotate(sub3(x, c), [0.0, 0.0, 1.0], 0.1);
                [r[0] + c[0], r[1] + c[1], r[2] + c[2]]
            })
            .collect();
        let adv = phase_advance(&pts, &after, &w, [0.0, 0.0, 1.0]);
        assert!((adv - 0.1).abs() < 1e-12, "{adv}");
    }
}
