//! Geometry of solvent particles against moving membrane triangles: the first time a straight
//! particle path crosses a linearly moving triangle (for bounce-back), and whether a point is
//! inside a closed triangulated surface (for the leak count).
//!
//! # Crossing a moving triangle
//!
//! Over one time step the particle moves on `P(t) = p₀ + t Δp` and the triangle's vertices on
//! `A(t) = a₀ + t Δa` (same for `B`, `C`), `t ∈ [0, 1]` the fraction of the step. The particle
//! is in the triangle's plane when
//!
//! ```text
//! F(t) = (P(t) − A(t)) · N(t) = 0,    N(t) = (B(t) − A(t)) × (C(t) − A(t)),
//! ```
//!
//! a cubic in `t`: with `r = r₀ + t r₁` (`r₀ = p₀ − a₀`, `r₁ = Δp − Δa`), `B − A = u₀ + t u₁`,
//! `C − A = v₀ + t v₁`, `N = n₀ + t n₁ + t² n₂` (`n₀ = u₀×v₀`, `n₁ = u₀×v₁ + u₁×v₀`,
//! `n₂ = u₁×v₁`) and
//!
//! ```text
//! F(t) = r₀·n₀ + t (r₀·n₁ + r₁·n₀) + t² (r₀·n₂ + r₁·n₁) + t³ r₁·n₂.
//! ```
//!
//! The roots in `(0, 1]` are found without the cubic formula (which loses digits when the
//! leading coefficients are tiny, the usual case of slowly moving triangles): the zeros of
//! `F′` (a quadratic) split `[0, 1]` into at most three intervals on which `F` is monotone,
//! and each interval whose ends differ in sign is bisected to the last bit. The earliest root
//! at which `P(t)` lies inside the triangle (barycentric coordinates `≥ −10⁻¹⁰`, so that a path
//! through a shared edge is caught by one of its two triangles) is the crossing. This is the
//! test Mirheo uses for its bounce-back (Alexeev et al. 2020), written here from the equation.
//!
//! # Inside a closed surface
//!
//! The solid angle of triangle `(a, b, c)` seen from `x` (Van Oosterom & Strackee 1983), with
//! `a, b, c` relative to `x`,
//!
//! ```text
//! tan(Ω/2) = a·(b × c) / (|a||b||c| + (a·b)|c| + (a·c)|b| + (b·c)|a|),
//! ```
//!
//! sums over a closed, outward-oriented surface to `4π` inside and `0` outside (the winding
//! number times `4π`); the point is inside when the sum exceeds `2π`.

/// A crossing of a particle path with a moving triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// Fraction of the step at which the particle meets the triangle's plane, in `(0, 1]`.
    pub t: f64,
    /// Barycentric coordinates `(λ_a, λ_b, λ_c)` of the meeting point in the triangle at `t`.
    pub bary: [f64; 3],
    /// The side the particle came from: `+1` if it arrived from the side the normal
    /// `(B − A) × (C − A)` points to (outside, for an outward-oriented surface), `−1` if not
    /// (the sign of `F` just before the crossing).
    pub side: f64,
}

#[inline]
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

#[inline]
fn lerp(a: [f64; 3], d: [f64; 3], t: f64) -> [f64; 3] {
    [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]]
}

/// Tolerance on the barycentric coordinates of a crossing (a path through an edge or a vertex
/// is caught by every triangle that shares it).
const BARY_TOL: f64 = 1e-10;

/// Barycentric coordinates of `q` projected onto the plane of triangle `(a, b, c)`; `None` for
/// a degenerate triangle.
pub fn barycentric(q: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> Option<[f64; 3]> {
    let (e1, e2, w) = (sub(b, a), sub(c, a), sub(q, a));
    let (d00, d01, d11) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
    let (d20, d21) = (dot(w, e1), dot(w, e2));
    let den = d00 * d11 - d01 * d01;
    if den <= 1e-300 * d00.max(d11).max(1.0) || !den.is_finite() {
        return None;
    }
    let lb = (d11 * d20 - d01 * d21) / den;
    let lc = (d00 * d21 - d01 * d20) / den;
    Some([1.0 - lb - lc, lb, lc])
}

/// The first crossing in `(0, 1]` of the path `p0 → p1` with the triangle moving from
/// `tri0 = [a₀, b₀, c₀]` to `tri1 = [a₁, b₁, c₁]` (see the module docs); `None` if the path
/// does not meet it, or starts exactly in its plane.
pub fn first_crossing(
    p0: [f64; 3],
    p1: [f64; 3],
    tri0: [[f64; 3]; 3],
    tri1: [[f64; 3]; 3],
) -> Option<Crossing> {
    let [a0, b0, c0] = tri0;
    let da = sub(tri1[0], a0);
    let (db, dc) = (sub(tri1[1], b0), sub(tri1[2], c0));
    let dp = sub(p1, p0);
    let r0 = sub(p0, a0);
    let r1 = sub(dp, da);
    let (u0, u1) = (sub(b0, a0), sub(db, da));
    let (v0, v1) = (sub(c0, a0), sub(dc, da));
    let n0 = cross(u0, v0);
    let n1 = {
        let (x, y) = (cross(u0, v1), cross(u1, v0));
        [x[0] + y[0], x[1] + y[1], x[2] + y[2]]
    };
    let n2 = cross(u1, v1);
    let c = [
        dot(r0, n0),
        dot(r0, n1) + dot(r1, n0),
        dot(r0, n2) + dot(r1, n1),
        dot(r1, n2),
    ];
    let f = |t: f64| ((c[3] * t + c[2]) * t + c[1]) * t + c[0];
    let f0 = c[0];
    if f0 == 0.0 || !f0.is_finite() {
        return None;
    }
    // Quick rejection: |F(t) − F(0)| ≤ |c₁| + |c₂| + |c₃| on [0, 1].
    if f0.abs() > c[1].abs() + c[2].abs() + c[3].abs() {
        return None;
    }
    // Break points: 0, the zeros of F′ = c₁ + 2c₂ t + 3c₃ t² inside (0, 1), and 1.
    let mut breaks = [0.0, 1.0, 1.0, 1.0];
    let mut nb = 1;
    let (qa, qb, qc) = (3.0 * c[3], 2.0 * c[2], c[1]);
    let mut push = |t: f64| {
        if t > 0.0 && t < 1.0 {
            breaks[nb] = t;
            nb += 1;
        }
    };
    if qa != 0.0 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            // Stable roots of the quadratic.
            let s = disc.sqrt();
            let q = -0.5 * (qb + qb.signum() * s);
            let (t1, t2) = if q != 0.0 {
                (q / qa, qc / q)
            } else {
                (-qb / (2.0 * qa), -qb / (2.0 * qa))
            };
            let (lo, hi) = if t1 <= t2 { (t1, t2) } else { (t2, t1) };
            push(lo);
            push(hi);
        }
    } else if qb != 0.0 {
        push(-qc / qb);
    }
    breaks[nb] = 1.0;
    let mut lo_val = f0;
    for k in 0..nb {
        let (mut lo, mut hi) = (breaks[k], breaks[k + 1]);
        let hi_val = f(hi);
        let crosses = lo_val != 0.0 && (hi_val == 0.0 || hi_val.signum() != lo_val.signum());
        let next_lo_val = hi_val;
        if crosses {
            // Bisect to the last bit: the root is the first t with sign(F) ≠ side.
            let sgn_lo = lo_val.signum();
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                let fm = f(mid);
                if fm != 0.0 && fm.signum() == sgn_lo {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let t = hi;
            let side = sgn_lo;
            let q = lerp(p0, dp, t);
            let tri = [lerp(a0, da, t), lerp(b0, db, t), lerp(c0, dc, t)];
            if let Some(bary) = barycentric(q, tri[0], tri[1], tri[2]) {
                if bary.iter().all(|&l| l >= -BARY_TOL) {
                    return Some(Crossing { t, bary, side });
                }
            }
        }
        lo_val = next_lo_val;
    }
    None
}

/// The signed solid angle of triangle `(a, b, c)` seen from `x`: positive when `x` is on the
/// side opposite the normal `(b − a) × (c − a)` (inside, for an outward-oriented surface).
pub fn solid_angle(x: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let (a, b, c) = (sub(a, x), sub(b, x), sub(c, x));
    let (la, lb, lc) = (norm(a), norm(b), norm(c));
    let num = dot(a, cross(b, c));
    let den = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    2.0 * num.atan2(den)
}

/// Whether `x` is inside the closed, outward-oriented surface with vertices `v` and triangles
/// `tris` (the winding number, from the solid angles, above one half).
pub fn inside(x: [f64; 3], v: &[[f64; 3]], tris: &[[usize; 3]]) -> bool {
    let omega: f64 = tris
        .iter()
        .map(|&[a, b, c]| solid_angle(x, v[a], v[b], v[c]))
        .sum();
    omega > 2.0 * std::f64::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// Reference: sample the path finely, find the first sample where `F` changes sign and the
    /// point is inside the triangle, and return that `t` (accurate to the sampling step).
    fn sampled_crossing(
        p0: [f64; 3],
        p1: [f64; 3],
        tri0: [[f64; 3]; 3],
        tri1: [[f64; 3]; 3],
        samples: usize,
    ) -> Option<f64> {
        let at = |t: f64| {
            let p = lerp(p0, sub(p1, p0), t);
            let tri: Vec<[f64; 3]> = (0..3)
                .map(|k| lerp(tri0[k], sub(tri1[k], tri0[k]), t))
                .collect();
            let n = cross(sub(tri[1], tri[0]), sub(tri[2], tri[0]));
            (dot(sub(p, tri[0]), n), p, tri)
        };
        let (f0, _, _) = at(0.0);
        for s in 1..=samples {
            let t = s as f64 / samples as f64;
            let (f, p, tri) = at(t);
            if f.signum() != f0.signum() {
                let l = barycentric(p, tri[0], tri[1], tri[2]).unwrap();
                if l.iter().all(|&x| x >= -1e-3) {
                    return Some(t);
                }
                // Sign changed outside the triangle: look for a later crossing from here.
                return sampled_crossing(
                    p,
                    p1,
                    [tri[0], tri[1], tri[2]],
                    tri1,
                    ((1.0 - t) * samples as f64) as usize + 1,
                )
                .map(|u| t + u * (1.0 - t));
            }
        }
        None
    }

    #[test]
    fn static_triangle_straight_path() {
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let c = first_crossing([0.25, 0.25, 0.3], [0.25, 0.25, -0.1], tri, tri).unwrap();
        assert!((c.t - 0.75).abs() < 1e-15, "t = {}", c.t);
        assert_eq!(c.side, 1.0);
        assert!((c.bary[1] - 0.25).abs() < 1e-14 && (c.bary[2] - 0.25).abs() < 1e-14);
        // Missing the triangle, or not reaching the plane.
        assert!(first_crossing([0.8, 0.8, 0.3], [0.8, 0.8, -0.1], tri, tri).is_none());
        assert!(first_crossing([0.2, 0.2, 0.3], [0.2, 0.2, 0.1], tri, tri).is_none());
    }

    #[test]
    fn a_triangle_overtaking_a_resting_particle() {
        // The particle rests at z = 0.5; the triangle moves up from z = 0 to z = 1: t = 1/2,
        // the particle was on the normal's side.
        let tri0 = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let tri1 = tri0.map(|v| [v[0], v[1], v[2] + 1.0]);
        let p = [0.2, 0.2, 0.5];
        let c = first_crossing(p, p, tri0, tri1).unwrap();
        assert!((c.t - 0.5).abs() < 1e-15);
        assert_eq!(c.side, 1.0);
    }

    #[test]
    fn first_crossing_matches_fine_sampling_on_random_moving_triangles() {
        let mut rng = StdRng::seed_from_u64(7);
        let mut hits = 0;
        let mut rv = |s: f64| -> [f64; 3] {
            [
                rng.random_range(-s..s),
                rng.random_range(-s..s),
                rng.random_range(-s..s),
            ]
        };
        for case in 0..6000 {
            let tri0 = [rv(1.0), rv(1.0), rv(1.0)];
            // Vertices move and the triangle turns (each vertex its own displacement).
            let tri1 = [0, 1, 2].map(|k| {
                let d = rv(0.4);
                [tri0[k][0] + d[0], tri0[k][1] + d[1], tri0[k][2] + d[2]]
            });
            let p0 = rv(1.0);
            let d = rv(1.5);
            let p1 = [p0[0] + d[0], p0[1] + d[1], p0[2] + d[2]];
            let exact = first_crossing(p0, p1, tri0, tri1);
            let sampled = sampled_crossing(p0, p1, tri0, tri1, 20_000);
            match (exact, sampled) {
                (Some(c), Some(t)) => {
                    hits += 1;
                    assert!((c.t - t).abs() < 2e-4, "case {case}: {} vs {t}", c.t);
                    // The point is on the plane of the triangle at t.
                    let q = lerp(p0, sub(p1, p0), c.t);
                    let tri: Vec<[f64; 3]> = (0..3)
                        .map(|k| lerp(tri0[k], sub(tri1[k], tri0[k]), c.t))
                        .collect();
                    let n = cross(sub(tri[1], tri[0]), sub(tri[2], tri[0]));
                    let dist = dot(sub(q, tri[0]), n) / norm(n);
                    assert!(dist.abs() < 1e-9, "case {case}: off the plane by {dist}");
                }
                (None, None) => {}
                // Grazing cases (the sampled path touching within the sampling tolerance)
                // may disagree: only when the crossing is at the triangle's border or the
                // path touches the plane tangentially.
                (Some(c), None) => {
                    assert!(
                        c.bary.iter().any(|&l| l < 1e-3),
                        "case {case}: exact {c:?}, sampling found none"
                    );
                }
                (None, Some(t)) => {
                    let q = lerp(p0, sub(p1, p0), t);
                    let tri: Vec<[f64; 3]> = (0..3)
                        .map(|k| lerp(tri0[k], sub(tri1[k], tri0[k]), t))
                        .collect();
                    let l = barycentric(q, tri[0], tri[1], tri[2]).unwrap();
                    assert!(
                        l.iter().any(|&x| x < 1e-3),
                        "case {case}: sampling found t = {t} (bary {l:?}), exact none"
                    );
                }
            }
        }
        assert!(hits > 180, "only {hits} crossings among the random cases");
    }

    #[test]
    fn winding_number_of_an_octahedron() {
        let (v, t) = crate::dpd::membrane::test_support::octahedron();
        let total: f64 = t
            .iter()
            .map(|&[a, b, c]| solid_angle([0.1, -0.2, 0.05], v[a], v[b], v[c]))
            .sum();
        assert!(
            (total - 4.0 * std::f64::consts::PI).abs() < 1e-12,
            "{total}"
        );
        assert!(inside([0.1, -0.2, 0.05], &v, &t));
        assert!(inside([0.3, 0.3, 0.3], &v, &t)); // |x|₁ = 0.9 < 1
        assert!(!inside([0.4, 0.4, 0.4], &v, &t)); // |x|₁ = 1.2 > 1
        assert!(!inside([3.0, 0.0, 0.0], &v, &t));
    }
}
