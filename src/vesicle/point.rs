//! Evaluation of a surface and its derivatives at arbitrary parameter points, and the closest
//! surface point to a target (shared by off-surface evaluation and reparametrisation).

use std::f64::consts::PI;

use super::dot;
use crate::sph_harmonics::legendre::{legendre_derivative_tables, tri_index, tri_len};
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
    val: Vec<f64>,
    d1: Vec<f64>,
    d2: Vec<f64>,
}

impl PointEval {
    pub(crate) fn new(p: usize) -> Self {
        PointEval {
            val: vec![0.0; tri_len(p)],
            d1: vec![0.0; tri_len(p)],
            d2: vec![0.0; tri_len(p)],
        }
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
        let nc = lay.len();
        let (s, c) = theta.sin_cos();
        legendre_derivative_tables(p, c, s, &mut self.val, &mut self.d1, &mut self.d2);
        let mut out = PointDerivs::default();
        for m in 0..=p {
            let norm = if m == 0 { (2.0 * PI).sqrt() } else { PI.sqrt() };
            let mf = m as f64;
            let (sm, cm) = (mf * phi).sin_cos();
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
    ((t, f), pd)
}
