//! Evaluation of a surface and its derivatives at arbitrary parameter points, and the closest
//! surface point to a target (shared by off-surface evaluation and reparametrisation).

use std::f64::consts::PI;

use super::dot;
use crate::sph_harmonics::legendre::{tri_index, tri_len, LegendreRecurrence};
use crate::sph_harmonics::CoefLayout;

/// Values and derivatives of a surface at one parameter point.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PointDerivs {
    pub(crate) x: [f64; 3],
    pub(crate) xt: [f64; 3],
    pub(crate) xp: [f64; 3],
    pub(crate) xtt: [f64; 3],
    pub(crate) xtp: [f64; 3],
    pub(crate) xpp: [f64; 3],
}

/// Scratch for evaluating expansions at arbitrary points.
pub(crate) struct PointEval {
    rec: LegendreRecurrence,
    val: Vec<f64>,
    d1: Vec<f64>,
    d2: Vec<f64>,
    /// `(sin mφ, cos mφ)` for `m = 0 … p`.
    trig: Vec<(f64, f64)>,
}

impl PointEval {
    pub(crate) fn new(p: usize) -> Self {
        PointEval {
            rec: LegendreRecurrence::new(p),
            val: vec![0.0; tri_len(p)],
            d1: vec![0.0; tri_len(p)],
            d2: vec![0.0; tri_len(p)],
            trig: vec![(0.0, 1.0); p + 1],
        }
    }

    /// `(sin mφ, cos mφ)` for `m = 0 … p` into `self.trig`, by the angle-addition recurrence
    /// from one `sin_cos` (accurate to a few ulps at these orders).
    fn fill_trig(&mut self, p: usize, phi: f64) {
        let (s1, c1) = phi.sin_cos();
        let (mut s, mut c) = (0.0, 1.0);
        for t in self.trig[..=p].iter_mut() {
            *t = (s, c);
            (s, c) = (s * c1 + c * s1, c * c1 - s * s1);
        }
    }

    /// The Legendre values and `(sin mφ, cos mφ)` at `(θ, φ)` for the layout `lay` (its
    /// order, returned, must be the planned one).
    fn values_at(&mut self, lay: &CoefLayout, theta: f64, phi: f64) -> usize {
        let p = lay.order();
        assert_eq!(
            p,
            self.rec.order(),
            "point evaluation planned for another order"
        );
        let (s, c) = theta.sin_cos();
        self.rec.table(c, s, &mut self.val);
        self.fill_trig(p, phi);
        p
    }

    /// Order `m` of the point of the last [`Self::values_at`]: the normalisation, `sin mφ`,
    /// `cos mφ` and `P̄_n^m(cos θ)` for `n = m … p`.
    fn order_m(&self, p: usize, m: usize) -> (f64, f64, f64, &[f64]) {
        let norm = if m == 0 {
            1.0 / (2.0 * PI).sqrt()
        } else {
            1.0 / PI.sqrt()
        };
        let (sm, cm) = self.trig[m];
        let base = tri_index(p, m, m);
        (norm, sm, cm, &self.val[base..base + p + 1 - m])
    }

    /// The three values `X(θ, φ)` alone of `x, y, z` coefficients (what a relabelling needs).
    pub(crate) fn eval_values(
        &mut self,
        lay: &CoefLayout,
        coefs: &[f64],
        theta: f64,
        phi: f64,
    ) -> [f64; 3] {
        let p = self.values_at(lay, theta, phi);
        let nc = lay.len();
        let mut out = [0.0; 3];
        for m in 0..=p {
            let (norm, sm, cm, val) = self.order_m(p, m);
            let cb = lay.cos_block(m);
            for (comp, o) in out.iter_mut().enumerate() {
                let cos_part: f64 = val
                    .iter()
                    .zip(&coefs[comp * nc + cb..comp * nc + cb + p + 1 - m])
                    .map(|(v, a)| v * a)
                    .sum();
                let sin_part: f64 = lay.sin_block(m).map_or(0.0, |sb| {
                    val.iter()
                        .zip(&coefs[comp * nc + sb..comp * nc + sb + p + 1 - m])
                        .map(|(v, b)| v * b)
                        .sum()
                });
                *o += norm * (cos_part * cm + sin_part * sm);
            }
        }
        out
    }

    /// The basis functions of the layout `lay` at `(θ, φ)` into `row` (`lay.len()` values, in
    /// the layout's order): `Σ_k row[k] c[k]` is [`Self::eval_values`] of one function, so
    /// one row serves any number of functions evaluated at the same point (a relabelling's
    /// passengers).
    pub(crate) fn basis_row(&mut self, lay: &CoefLayout, theta: f64, phi: f64, row: &mut [f64]) {
        assert_eq!(row.len(), lay.len(), "basis row of another layout");
        let p = self.values_at(lay, theta, phi);
        for m in 0..=p {
            let (norm, sm, cm, val) = self.order_m(p, m);
            let cb = lay.cos_block(m);
            for (r, v) in row[cb..cb + p + 1 - m].iter_mut().zip(val) {
                *r = norm * cm * v;
            }
            if let Some(sb) = lay.sin_block(m) {
                for (r, v) in row[sb..sb + p + 1 - m].iter_mut().zip(val) {
                    *r = norm * sm * v;
                }
            }
        }
    }

    /// The outward normal `X_θ × X_φ` (not normalised) at `u = (θ, φ)`, with `pd` the
    /// derivatives there. At a pole `X_φ` vanishes and the cross product has no direction of
    /// its own; there `X_θ(φ)` is linear in `(cos φ, sin φ)`, so `X_φ/sin θ → ±X_θ(φ + π/2)`
    /// (`+` at θ = 0, `−` at θ = π) and the limit `±X_θ(φ) × X_θ(φ + π/2)` is returned.
    pub(crate) fn normal(
        &mut self,
        lay: &CoefLayout,
        coefs: &[f64],
        u: (f64, f64),
        pd: &PointDerivs,
    ) -> [f64; 3] {
        let nv = super::cross(pd.xt, pd.xp);
        if dot(nv, nv).sqrt() > 1e-8 * dot(pd.xt, pd.xt) {
            return nv;
        }
        let quarter = self.eval(lay, coefs, u.0, u.1 + 0.5 * PI);
        let sign = if u.0 < 0.5 * PI { 1.0 } else { -1.0 };
        super::cross(pd.xt, quarter.xt).map(|v| sign * v)
    }

    /// `X` and its first and second derivatives at `(θ, φ)` for `x, y, z` coefficients.
    pub(crate) fn eval(
        &mut self,
        lay: &CoefLayout,
        coefs: &[f64],
        theta: f64,
        phi: f64,
    ) -> PointDerivs {
        let p = lay.order();
        assert_eq!(
            p,
            self.rec.order(),
            "point evaluation planned for another order"
        );
        let nc = lay.len();
        let (s, c) = theta.sin_cos();
        self.rec
            .derivative_tables(c, s, &mut self.val, &mut self.d1, &mut self.d2);
        self.fill_trig(p, phi);
        let mut out = PointDerivs::default();
        for m in 0..=p {
            let norm = if m == 0 { (2.0 * PI).sqrt() } else { PI.sqrt() };
            let mf = m as f64;
            let (sm, cm) = self.trig[m];
            for n in m..=p {
                let t = tri_index(p, n, m);
                let (v, d1, d2) = (self.val[t] / norm, self.d1[t] / norm, self.d2[t] / norm);
                for comp in 0..3 {
                    let a = coefs[comp * nc + lay.cos_block(m) + n - m];
                    let b = lay
                        .sin_block(m)
                        .map_or(0.0, |o| coefs[comp * nc + o + n - m]);
                    // a cos mφ + b sin mφ and its φ-derivatives.
                    let f0 = a * cm + b * sm;
                    let f1 = mf * (b * cm - a * sm);
                    let f2 = -mf * mf * f0;
                    out.x[comp] += v * f0;
                    out.xt[comp] += d1 * f0;
                    out.xp[comp] += v * f1;
                    out.xtt[comp] += d2 * f0;
                    out.xtp[comp] += d1 * f1;
                    out.xpp[comp] += v * f2;
                }
            }
        }
        out
    }
}

/// Closest surface point to `x` by Newton's method on `½|X(θ, φ) − x|²` from `start`
/// (Gauss–Newton where the Hessian is not positive definite); returns its parameters and the
/// surface derivatives there.
pub(crate) fn closest_point(
    pe: &mut PointEval,
    lay: &CoefLayout,
    coefs: &[f64],
    x: [f64; 3],
    start: (f64, f64),
) -> ((f64, f64), PointDerivs) {
    let (mut t, mut f) = start;
    let mut pd = pe.eval(lay, coefs, t, f);
    for _ in 0..60 {
        let r = [pd.x[0] - x[0], pd.x[1] - x[1], pd.x[2] - x[2]];
        let g = [dot(pd.xt, r), dot(pd.xp, r)];
        let jtj = [dot(pd.xt, pd.xt), dot(pd.xt, pd.xp), dot(pd.xp, pd.xp)];
        let mut h = [
            jtj[0] + dot(pd.xtt, r),
            jtj[1] + dot(pd.xtp, r),
            jtj[2] + dot(pd.xpp, r),
        ];
        let mut det = h[0] * h[2] - h[1] * h[1];
        if !(det > 0.0 && h[0] > 0.0) {
            h = jtj;
            det = h[0] * h[2] - h[1] * h[1];
        }
        let dt = -(h[2] * g[0] - h[1] * g[1]) / det;
        let dp = -(h[0] * g[1] - h[1] * g[0]) / det;
        if !(dt.is_finite() && dp.is_finite()) {
            break;
        }
        t += dt;
        f += dp;
        pd = pe.eval(lay, coefs, t, f);
        if dt.abs() + dp.abs() < 1e-15 {
            break;
        }
    }
    // Newton may have stepped across a pole: the point is the same, but there `X_θ × X_φ`
    // points inward; its angles with θ in [0, π] give the outward normal.
    let (tc, fc) = canonical_angles(t, f);
    if tc != t {
        pd = pe.eval(lay, coefs, tc, fc);
    }
    ((tc, fc), pd)
}

/// The angles of the same surface point with `θ ∈ [0, π]`: `X(θ, φ) = X(2π − θ, φ + π)` (the
/// basis has the factor `sinᵐθ` and `cos m(φ + π) = (−1)ᵐ cos mφ`), and only for `θ ∈ [0, π]`
/// is the orientation of `(θ, φ)`, hence `X_θ × X_φ`, outward.
fn canonical_angles(theta: f64, phi: f64) -> (f64, f64) {
    let t = theta.rem_euclid(2.0 * PI);
    if t > PI {
        (2.0 * PI - t, phi + PI)
    } else {
        (t, phi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `eval_values` (the values alone) is `eval`'s `x` and the basis row's sum, also near and at
    /// the poles; and `eval`
    /// with the precomputed recurrence and trigonometric recurrence matches the closed-form
    /// basis of the reference module.
    #[test]
    fn values_alone_equal_the_full_evaluation() {
        for p in [3usize, 12, 24] {
            let lay = CoefLayout::new(p);
            let nc = lay.len();
            let mut s = 7u64;
            let coefs: Vec<f64> = (0..3 * nc)
                .map(|_| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .collect();
            let mut pe = PointEval::new(p);
            for (theta, phi) in [(0.3, 1.1), (1e-9, -2.0), (PI - 1e-7, 0.4), (1.9, 5.9)] {
                let full = pe.eval(&lay, &coefs, theta, phi);
                let x = pe.eval_values(&lay, &coefs, theta, phi);
                let mut want = [0.0; 3];
                for (k, &(n, m)) in lay.modes().iter().enumerate() {
                    let y = crate::sph_harmonics::reference::ylm(n, m, theta, phi);
                    for c in 0..3 {
                        want[c] += coefs[c * nc + k] * y;
                    }
                }
                let mut row = vec![0.0; nc];
                pe.basis_row(&lay, theta, phi, &mut row);
                for c in 0..3 {
                    let by_row: f64 = row
                        .iter()
                        .zip(&coefs[c * nc..(c + 1) * nc])
                        .map(|(r, a)| r * a)
                        .sum();
                    assert!(
                        (by_row - x[c]).abs() < 1e-13,
                        "p = {p}: basis row {by_row} vs {}",
                        x[c]
                    );
                }
                for c in 0..3 {
                    assert!(
                        (x[c] - full.x[c]).abs() < 1e-13,
                        "p = {p}: {x:?} vs {:?}",
                        full.x
                    );
                    assert!((x[c] - want[c]).abs() < 1e-12, "p = {p}: {x:?} vs {want:?}");
                }
            }
        }
    }

    /// Newton's closest point may step across a pole (θ < 0 or θ > π), where the point is
    /// still on the surface but `X_θ × X_φ` points inward: the returned angles are brought back
    /// to θ ∈ [0, π], so the normal there is outward and the side of the target is right (a
    /// point outside an ellipsoid near its pole, Newton started across the pole).
    #[test]
    fn the_closest_point_across_a_pole_keeps_the_outward_normal() {
        let (a, b, c) = (1.3, 0.9, 0.6);
        let ellipsoid =
            |t: f64, f: f64| [a * t.sin() * f.cos(), b * t.sin() * f.sin(), c * t.cos()];
        let p = 8;
        let surface = super::super::shapes::Surface::from_fn(p, ellipsoid).unwrap();
        let coefs = surface.coefs().to_vec();
        let lay = CoefLayout::new(p);
        let mut pe = PointEval::new(p);
        for (t0, f0, lift) in [(0.15, 0.3, 0.2), (0.05, 2.0, 0.05), (PI - 0.1, 4.0, 0.3)] {
            let on = pe.eval(&lay, &coefs, t0, f0);
            let nv = pe.normal(&lay, &coefs, (t0, f0), &on);
            let len = dot(nv, nv).sqrt();
            // Outside, above the surface point (t0, f0); start from the point across the pole.
            let x: [f64; 3] = std::array::from_fn(|k| on.x[k] + lift * nv[k] / len);
            let start = (t0, f0 + PI);
            let (u, pd) = closest_point(&mut pe, &lay, &coefs, x, start);
            assert!((0.0..=PI).contains(&u.0), "θ = {} outside [0, π]", u.0);
            let n = pe.normal(&lay, &coefs, u, &pd);
            let r = [x[0] - pd.x[0], x[1] - pd.x[1], x[2] - pd.x[2]];
            let d = dot(r, r).sqrt();
            assert!(
                (d - lift).abs() < 1e-3 * lift,
                "distance {d} for a point {lift} above the surface"
            );
            assert!(
                dot(r, n) > 0.99 * d * dot(n, n).sqrt(),
                "the normal at the closest point must point to the outside target: r {r:?}, n {n:?}"
            );
        }
    }
}
