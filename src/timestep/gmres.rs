//! Restarted, right-preconditioned GMRES(m) (Saad & Schultz 1986); see the module docs of
//! [`crate::timestep`] for the mathematics.

use super::operator::{LinearOperator, Preconditioner};
use super::TimestepError;

/// Parameters of [`gmres`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GmresParams {
    /// Relative tolerance on the true residual: stop when `‖b − A x‖₂ ≤ tol ‖b‖₂`. Must be
    /// positive and finite.
    pub tol: f64,
    /// Restart length `m` (Krylov vectors per cycle), at least 1. Memory is `(m + 1) n` floats.
    pub restart: usize,
    /// Limit on the total number of Arnoldi steps (products with `A M⁻¹`) over all cycles.
    pub max_iters: usize,
    /// Stagnation test: a full restart cycle must lower the true residual by at least this
    /// fraction (`r_new ≤ (1 − min_cycle_reduction) r_old`), else the solve stops with
    /// [`TimestepError::Stagnated`] instead of grinding on to `max_iters`. Default `1e-3`: a
    /// cycle that gains less than 0.1 % would need thousands more per decade. `0` turns the
    /// test off (only an increase then counts).
    pub min_cycle_reduction: f64,
}

impl Default for GmresParams {
    /// `tol = 1e-8`, `restart = 50`, `max_iters = 1000`, `min_cycle_reduction = 1e-3`.
    fn default() -> Self {
        Self {
            tol: 1e-8,
            restart: 50,
            max_iters: 1000,
            min_cycle_reduction: 1e-3,
        }
    }
}

impl GmresParams {
    /// Check the ranges documented on the fields.
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] naming the offending field.
    pub fn validate(&self) -> Result<(), TimestepError> {
        if !(self.tol.is_finite() && self.tol > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "tol",
                value: format!("{}", self.tol),
                reason: "must be positive and finite",
            });
        }
        if !(self.min_cycle_reduction.is_finite() && (0.0..1.0).contains(&self.min_cycle_reduction))
        {
            return Err(TimestepError::InvalidParameter {
                name: "min_cycle_reduction",
                value: format!("{}", self.min_cycle_reduction),
                reason: "must lie in [0, 1)",
            });
        }
        if self.restart == 0 {
            return Err(TimestepError::InvalidParameter {
                name: "restart",
                value: "0".into(),
                reason: "must be at least 1",
            });
        }
        Ok(())
    }
}

/// What a GMRES solve did.
#[derive(Clone, Debug, PartialEq)]
pub struct GmresReport {
    /// Total Arnoldi steps (each one product with `M⁻¹` and one with `A`).
    pub iterations: usize,
    /// Number of restarts (cycles − 1; 0 when no cycle ran).
    pub restarts: usize,
    /// True relative residual `‖b − A x‖₂ / ‖b‖₂` of the returned `x`, recomputed from `x`
    /// (not the recurrence estimate).
    pub relative_residual: f64,
    /// `‖b − A x₀‖₂ / ‖b‖₂` of the initial guess (1 without one).
    pub initial_relative_residual: f64,
    /// Whether `relative_residual ≤ tol`.
    pub converged: bool,
    /// The tolerance that was asked for.
    pub tol: f64,
    /// True relative residual at the end of each cycle (non-increasing in exact arithmetic).
    pub cycle_residuals: Vec<f64>,
    /// Products with `A`, including the true-residual products (one per cycle, one more for a
    /// non-zero initial guess).
    pub operator_applications: usize,
    /// Applications of `M⁻¹` (one per iteration and one per cycle to form the iterate).
    pub preconditioner_applications: usize,
}

/// Storage for [`gmres`]: the Krylov basis `V ∈ ℝ^{n×(m+1)}`, the Hessenberg/triangular factor
/// `H ∈ ℝ^{(m+1)×m}`, the rotations and two work vectors, allocated once.
///
/// A solve of a different size `n` or restart length `m` reallocates it (at the start of the
/// solve, never during the iteration); solves of the same size reuse it without allocating.
#[derive(Clone, Debug, Default)]
pub struct GmresWorkspace {
    n: usize,
    m: usize,
    /// Column-major `n × (m+1)` basis.
    v: Vec<f64>,
    /// Column-major `(m+1) × m`.
    h: Vec<f64>,
    cs: Vec<f64>,
    sn: Vec<f64>,
    g: Vec<f64>,
    y: Vec<f64>,
    /// `‖A M⁻¹ v_j‖` before orthogonalisation, the scale of column `j` of `H̄`.
    colnorm: Vec<f64>,
    w: Vec<f64>,
    z: Vec<f64>,
}

impl GmresWorkspace {
    /// A workspace for systems of size `n` with restart length `restart`.
    pub fn new(n: usize, restart: usize) -> Self {
        let mut ws = Self::default();
        ws.ensure(n, restart);
        ws
    }

    /// `(n, m)` the workspace is currently sized for.
    pub fn size(&self) -> (usize, usize) {
        (self.n, self.m)
    }

    fn ensure(&mut self, n: usize, m: usize) {
        if self.n == n && self.m == m {
            return;
        }
        self.n = n;
        self.m = m;
        self.v = vec![0.0; n * (m + 1)];
        self.h = vec![0.0; (m + 1) * m];
        self.cs = vec![0.0; m];
        self.sn = vec![0.0; m];
        self.g = vec![0.0; m + 1];
        self.y = vec![0.0; m];
        self.colnorm = vec![0.0; m];
        self.w = vec![0.0; n];
        self.z = vec![0.0; n];
    }
}

/// `Σ a_i b_i` with eight independent partial sums (vectorises; fixed order, so deterministic).
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let ca = a.chunks_exact(8);
    let cb = b.chunks_exact(8);
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

/// `y ← y + α x`.
fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// Givens rotation `(c, s, r)` with `[c s; −s c] (a, b)ᵀ = (r, 0)ᵀ`.
fn givens(a: f64, b: f64) -> (f64, f64, f64) {
    if b == 0.0 {
        (1.0, 0.0, a)
    } else {
        let r = a.hypot(b);
        (a / r, b / r, r)
    }
}

/// Relative size of `‖w‖` after orthogonalisation, against before, under which the Krylov space
/// is taken as invariant (breakdown).
const BREAKDOWN: f64 = 8.0 * f64::EPSILON;

/// Short cycles in a row (ended by the residual estimate, not by the restart length) that do
/// not lower the best true residual before the solve is declared stagnated.
const SHORT_CYCLES_WITHOUT_PROGRESS: usize = 3;

/// Relative size of a pivot of `R` (against its column's scale) under which the column is taken as
/// linearly dependent on the previous ones.
const SINGULAR: f64 = 64.0 * f64::EPSILON;

/// Solve `A x = b` by restarted GMRES(m) with right preconditioner `M` (see the module docs of
/// [`crate::timestep`] for the method and the example).
///
/// `x0` is the initial guess (zero when `None`); the solution is written to `x`. On success the
/// report has `converged == true` and `relative_residual = ‖b − A x‖₂/‖b‖₂ ≤ tol` computed from
/// the returned `x`. For `b = 0` the answer is `x = 0` with no iteration.
///
/// # Errors
/// * [`TimestepError::DimensionMismatch`] / [`TimestepError::NotSquare`]: `A` not square, or `b`,
///   `x`, `x0`, `M` not of size `n = A.nrows()`;
/// * [`TimestepError::InvalidParameter`]: see [`GmresParams::validate`];
/// * [`TimestepError::NonFinite`]: NaN/∞ in `b` or `x0`, or produced by `A` or `M`;
/// * [`TimestepError::NotConverged`]: `max_iters` reached; carries the report, `x` holds the last
///   iterate (whose true residual is the report's `relative_residual`);
/// * [`TimestepError::Breakdown`]: the Krylov space became invariant above the tolerance
///   (singular `A M⁻¹`); carries the report, `x` holds the last iterate.
/// * [`TimestepError::Stagnated`]: a full restart cycle lowered the true residual by less than
///   [`GmresParams::min_cycle_reduction`], or three short cycles in a row (ended because the
///   recurrence's residual estimate met the tolerance while the true residual did not: the
///   products' own errors are above `tol`) did not lower the best true residual by that
///   fraction; carries the report (with the residual after every cycle), `x` holds the last
///   iterate.
pub fn gmres<A, P>(
    a: &A,
    precond: &P,
    b: &[f64],
    x0: Option<&[f64]>,
    x: &mut [f64],
    params: &GmresParams,
    ws: &mut GmresWorkspace,
) -> Result<GmresReport, TimestepError>
where
    A: LinearOperator + ?Sized,
    P: Preconditioner + ?Sized,
{
    gmres_with(a, precond, b, x0, x, params, ws, &Local)
}

/// The inner products GMRES takes, and its agreement on a failed check: of the whole vectors
/// here ([`gmres`]), or summed over processes that each hold some rows of every vector (the
/// near-implicit step over MPI ranks), so that every process runs the same recurrence.
pub(crate) trait InnerProducts {
    /// `Σ a_i b_i` over the whole vectors.
    fn dot(&self, a: &[f64], b: &[f64]) -> f64;
    /// Whether `local` holds on any process.
    fn any(&self, local: bool) -> bool;
}

/// The inner products of vectors held whole.
struct Local;

impl InnerProducts for Local {
    fn dot(&self, a: &[f64], b: &[f64]) -> f64 {
        dot(a, b)
    }
    fn any(&self, local: bool) -> bool {
        local
    }
}

/// What [`gmres_with`] applies: a [`LinearOperator`] or, without its `Sync` bound, an operator
/// whose products are collective over ranks (applied from one thread).
pub(crate) trait GmresOperator {
    fn nrows(&self) -> usize;
    fn ncols(&self) -> usize;
    fn apply(&self, x: &[f64], y: &mut [f64]);
}

impl<T: LinearOperator + ?Sized> GmresOperator for T {
    fn nrows(&self) -> usize {
        LinearOperator::nrows(self)
    }
    fn ncols(&self) -> usize {
        LinearOperator::ncols(self)
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        LinearOperator::apply(self, x, y)
    }
}

/// [`gmres`] with the inner products of `ip` (each process passes its rows of `b`, `x0`, `x`;
/// `a` and `precond` act on those rows, exchanging what they need). Over processes, the
/// parameter and size checks at the start return before any exchange: the callers pass the
/// same `params` everywhere and consistent sizes; every later branch follows shared sums.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gmres_with<A, P, I>(
    a: &A,
    precond: &P,
    b: &[f64],
    x0: Option<&[f64]>,
    x: &mut [f64],
    params: &GmresParams,
    ws: &mut GmresWorkspace,
    ip: &I,
) -> Result<GmresReport, TimestepError>
where
    A: GmresOperator + ?Sized,
    P: Preconditioner + ?Sized,
    I: InnerProducts + ?Sized,
{
    let norm = |v: &[f64]| ip.dot(v, v).sqrt();
    params.validate()?;
    let n = a.nrows();
    if a.ncols() != n {
        return Err(TimestepError::NotSquare {
            what: "operator A".into(),
            nrows: n,
            ncols: a.ncols(),
        });
    }
    let check = |what: &'static str, got: usize| {
        if got == n {
            Ok(())
        } else {
            Err(TimestepError::DimensionMismatch {
                what,
                expected: n,
                got,
            })
        }
    };
    check("right-hand side b", b.len())?;
    check("solution x", x.len())?;
    check("preconditioner M", precond.nrows())?;
    if let Some(x0) = x0 {
        check("initial guess x0", x0.len())?;
        if ip.any(x0.iter().any(|v| !v.is_finite())) {
            return Err(TimestepError::NonFinite {
                what: "initial guess x0",
            });
        }
    }
    if ip.any(b.iter().any(|v| !v.is_finite())) {
        return Err(TimestepError::NonFinite {
            what: "right-hand side b",
        });
    }

    let m = params.restart;
    let tol = params.tol;
    ws.ensure(n, m);
    let ld = m + 1; // leading dimension of H
    let GmresWorkspace {
        v,
        h,
        cs,
        sn,
        g,
        y,
        colnorm,
        w,
        z,
        ..
    } = ws;

    let mut report = GmresReport {
        iterations: 0,
        restarts: 0,
        relative_residual: 0.0,
        initial_relative_residual: 0.0,
        converged: true,
        tol,
        cycle_residuals: Vec::with_capacity(params.max_iters.div_ceil(m).min(1024) + 1),
        operator_applications: 0,
        preconditioner_applications: 0,
    };

    let norm_b = norm(b);
    if norm_b == 0.0 {
        x.fill(0.0);
        return Ok(report);
    }

    // r₀ = b − A x₀ into v₀.
    let (r, _) = v.split_at_mut(n);
    match x0 {
        Some(x0) => {
            x.copy_from_slice(x0);
            a.apply(x, w);
            report.operator_applications += 1;
            for ((ri, bi), wi) in r.iter_mut().zip(b).zip(w.iter()) {
                *ri = bi - wi;
            }
        }
        None => {
            x.fill(0.0);
            r.copy_from_slice(b);
        }
    }
    let mut beta = norm(r);
    if !beta.is_finite() {
        return Err(TimestepError::NonFinite {
            what: "operator output",
        });
    }
    let mut rel = beta / norm_b;
    report.initial_relative_residual = rel;
    let mut cycles = 0usize;
    // The smallest true residual so far, and how many short cycles in a row did not lower it.
    let mut best = rel;
    let mut idle_short = 0usize;

    loop {
        report.relative_residual = rel;
        report.restarts = cycles.saturating_sub(1);
        if rel <= tol {
            report.converged = true;
            return Ok(report);
        }
        report.converged = false;
        if report.iterations >= params.max_iters {
            return Err(TimestepError::NotConverged(report));
        }

        // One cycle of at most m Arnoldi steps from v₀ = r/β.
        cycles += 1;
        let inv = 1.0 / beta;
        v[..n].iter_mut().for_each(|vi| *vi *= inv);
        g.fill(0.0);
        g[0] = beta;
        let mut k = 0;
        let mut breakdown = false;
        for j in 0..m {
            if report.iterations >= params.max_iters {
                break;
            }
            // w = A M⁻¹ v_j
            precond.apply(&v[j * n..(j + 1) * n], z);
            a.apply(z, w);
            report.iterations += 1;
            report.operator_applications += 1;
            report.preconditioner_applications += 1;
            let norm0 = norm(w);
            if !norm0.is_finite() {
                return Err(TimestepError::NonFinite {
                    what: "operator or preconditioner output",
                });
            }
            colnorm[j] = norm0;
            // Modified Gram–Schmidt, with a second pass if cancellation was severe.
            let hj = &mut h[j * ld..(j + 1) * ld];
            for (i, hij) in hj.iter_mut().enumerate().take(j + 1) {
                let vi = &v[i * n..(i + 1) * n];
                *hij = ip.dot(vi, w);
                axpy(-*hij, vi, w);
            }
            let mut norm1 = norm(w);
            if norm1 < std::f64::consts::FRAC_1_SQRT_2 * norm0 {
                for (i, hij) in hj.iter_mut().enumerate().take(j + 1) {
                    let vi = &v[i * n..(i + 1) * n];
                    let c = ip.dot(vi, w);
                    *hij += c;
                    axpy(-c, vi, w);
                }
                norm1 = norm(w);
            }
            hj[j + 1] = norm1;
            if norm1 <= BREAKDOWN * norm0 {
                breakdown = true;
            } else {
                let inv = 1.0 / norm1;
                for (vn, wi) in v[(j + 1) * n..(j + 2) * n].iter_mut().zip(w.iter()) {
                    *vn = wi * inv;
                }
            }
            // Previous rotations, then a new one to annihilate h_{j+1,j}.
            for i in 0..j {
                let (hi, hi1) = (hj[i], hj[i + 1]);
                hj[i] = cs[i] * hi + sn[i] * hi1;
                hj[i + 1] = -sn[i] * hi + cs[i] * hi1;
            }
            let (c, s, rr) = givens(hj[j], hj[j + 1]);
            cs[j] = c;
            sn[j] = s;
            hj[j] = rr;
            hj[j + 1] = 0.0;
            g[j + 1] = -s * g[j];
            g[j] *= c;
            k = j + 1;
            if g[j + 1].abs() <= tol * norm_b || breakdown {
                break;
            }
        }

        // y = R⁻¹ g by back substitution. A pivot |r_ii| ≤ SINGULAR ‖A M⁻¹ v_i‖ means that
        // A M⁻¹ v_i lies (to working precision) in the span of the previous columns: A M⁻¹ is
        // singular on the Krylov space. That column is dropped (y_i = 0) rather than divided by
        // rounding noise; the true residual below tells what the iterate is worth.
        for i in (0..k).rev() {
            let mut s = g[i];
            for (l, yl) in y.iter().enumerate().take(k).skip(i + 1) {
                s -= h[l * ld + i] * yl;
            }
            let rii = h[i * ld + i];
            y[i] = if rii.abs() > SINGULAR * colnorm[i] {
                s / rii
            } else {
                0.0
            };
        }
        // x += M⁻¹ V_k y
        w.fill(0.0);
        for (i, yi) in y.iter().enumerate().take(k) {
            axpy(*yi, &v[i * n..(i + 1) * n], w);
        }
        precond.apply(w, z);
        report.preconditioner_applications += 1;
        for (xi, zi) in x.iter_mut().zip(z.iter()) {
            *xi += zi;
        }
        // True residual r = b − A x, the next start vector.
        a.apply(x, w);
        report.operator_applications += 1;
        for ((ri, bi), wi) in v[..n].iter_mut().zip(b).zip(w.iter()) {
            *ri = bi - wi;
        }
        beta = norm(&v[..n]);
        if !beta.is_finite() {
            return Err(TimestepError::NonFinite {
                what: "operator or preconditioner output",
            });
        }
        let previous = rel;
        rel = beta / norm_b;
        report.cycle_residuals.push(rel);
        if breakdown && rel > tol {
            report.relative_residual = rel;
            report.restarts = cycles - 1;
            report.converged = false;
            return Err(TimestepError::Breakdown(report));
        }
        // A cycle that ended early because the recurrence's residual estimate met the tolerance
        // while the true residual did not: the attainable-accuracy floor (the products carry
        // errors above `tol`). Short cycles then follow one another without progress; three in
        // a row that do not lower the best true residual by `min_cycle_reduction` stop the solve.
        let short = k < m && report.iterations < params.max_iters;
        let improved = rel <= (1.0 - params.min_cycle_reduction) * best;
        best = best.min(rel);
        idle_short = if short && !improved {
            idle_short + 1
        } else {
            0
        };
        // A full cycle that did not make progress: more cycles from the same place would not
        // either (a cycle cut short by max_iters is left to the NotConverged test).
        let full_idle = k == m && rel > (1.0 - params.min_cycle_reduction) * previous;
        if rel > tol && (full_idle || idle_short >= SHORT_CYCLES_WITHOUT_PROGRESS) {
            report.relative_residual = rel;
            report.restarts = cycles - 1;
            report.converged = false;
            return Err(TimestepError::Stagnated(report));
        }
    }
}
