//! Reparametrisation: remove tangential drift of the grid without changing the shape.
//!
//! Tangential velocities (tank-treading, shear) carry the material points along the surface and
//! concentrate the parametrisation, which moves spectral energy to high degrees. Following
//! Veerapaneni et al. (2011, §3.4) the grid is relaxed by descending the spectral energy
//!
//! `E(X) = Σ_n A_n |x̂_n|²`, `A_n = (n/p)^{2s}`,
//!
//! (the sum over all coefficients of degree `n` of the three coordinates) along the surface
//! only: with `G = Σ A_n x̂_n Y_n` on the grid (half the gradient of `E`) and `P = I − n⊗n`,
//! each step moves every grid point by the tangent vector `d = −τ P G`, taken in parameters
//! (`[E F; F G] δ = [X_θ·d; X_φ·d]`, one Gauss–Newton step of the closest-point problem) and
//! evaluated *on the current surface*, `X(θ + δθ, φ + δφ)`: every moved point lies on the
//! band-limited surface exactly, so the shape changes only by the re-fit of the moved points at
//! order `p` — below the discretisation error. (The exact closest point of `X + d`, by Newton's
//! method, cost 5–6 point evaluations per grid point instead of one, for a move that differs
//! only at second order in `|d|`.) The iteration
//! stops when a step lowers `E` by less than `tolerance · E` or would raise it.
//!
//! The grid-quality measure reported is `E` itself (the energy in the high degrees of the
//! parametrisation); [`ReparamReport`] gives it before and after.

use super::geometry::SurfaceCalculus;
use super::point::PointEval;
use super::shapes::Surface;
use super::{dot, VesicleError};
use crate::sph_harmonics::{CoefLayout, ShTransform, ShWorkspace};

/// Parameters of [`reparametrize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReparamParams {
    /// Exponent `s` of the weights `A_n = (n/p)^{2s}`.
    pub weight_exponent: u32,
    /// Step `τ` (stable for `τ < 1`, since `A_n ≤ 1`).
    pub step: f64,
    /// Maximum number of steps.
    pub max_iterations: usize,
    /// Stop when a step lowers the energy by less than this fraction.
    pub tolerance: f64,
}

impl Default for ReparamParams {
    fn default() -> Self {
        ReparamParams {
            weight_exponent: 2,
            step: 0.5,
            max_iterations: 100,
            tolerance: 1e-4,
        }
    }
}

/// What a reparametrisation did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReparamReport {
    /// `E = Σ A_n |x̂_n|²` before.
    pub energy_before: f64,
    /// `E` after.
    pub energy_after: f64,
    /// Steps taken (accepted).
    pub iterations: usize,
}

/// The spectral energy `Σ_n (n/p)^{2s} |x̂_n|²` of a surface's coefficients.
pub fn spectral_energy(surface: &Surface, weight_exponent: u32) -> f64 {
    let lay = CoefLayout::new(surface.order());
    let w = weights(&lay, weight_exponent);
    let nc = lay.len();
    surface
        .coefs()
        .chunks_exact(nc)
        .map(|c| c.iter().zip(&w).map(|(a, w)| w * a * a).sum::<f64>())
        .sum()
}

fn weights(lay: &CoefLayout, s: u32) -> Vec<f64> {
    let p = lay.order() as f64;
    lay.degrees()
        .iter()
        .map(|&n| (n as f64 / p).powi(2 * s as i32))
        .collect()
}

/// Reparametrise `surface` in place (see the module docs). Plans the transforms on every call:
/// a time stepper keeps a [`Reparametrizer`] instead.
pub fn reparametrize(
    surface: &mut Surface,
    params: &ReparamParams,
) -> Result<ReparamReport, VesicleError> {
    Reparametrizer::new(surface.order())?.run(surface, params)
}

/// The transforms and scratch of [`reparametrize`] for surfaces of one order, planned once.
pub struct Reparametrizer {
    sht: ShTransform,
    ws: ShWorkspace,
    calc: SurfaceCalculus,
    pe: PointEval,
    gc: Vec<f64>,
    g: Vec<f64>,
    moved: Vec<f64>,
    new_coefs: Vec<f64>,
}

impl Reparametrizer {
    /// Plans for order `p`.
    pub fn new(p: usize) -> Result<Self, VesicleError> {
        let sht = ShTransform::new(p)?;
        let (nc, np) = (sht.n_coefs(), sht.n_points());
        Ok(Reparametrizer {
            ws: sht.workspace(),
            calc: SurfaceCalculus::new(p)?,
            pe: PointEval::new(p),
            gc: vec![0.0; 3 * nc],
            g: vec![0.0; 3 * np],
            moved: vec![0.0; 3 * np],
            new_coefs: vec![0.0; 3 * nc],
            sht,
        })
    }

    /// Reparametrise `surface` (of this order) in place (see the module docs).
    pub fn run(
        &mut self,
        surface: &mut Surface,
        params: &ReparamParams,
    ) -> Result<ReparamReport, VesicleError> {
        if surface.order() != self.sht.order() {
            return Err(VesicleError::Parameter {
                name: "surface order",
                value: surface.order() as f64,
                reason: "differs from the order the reparametrisation was planned for",
            });
        }
        reparametrize_with(self, surface, params)
    }
}

fn reparametrize_with(
    plan: &mut Reparametrizer,
    surface: &mut Surface,
    params: &ReparamParams,
) -> Result<ReparamReport, VesicleError> {
    if !(params.step.is_finite() && params.step > 0.0 && params.step < 1.0) {
        return Err(VesicleError::Parameter {
            name: "reparametrisation step",
            value: params.step,
            reason: "must lie in (0, 1)",
        });
    }
    if !(params.tolerance.is_finite() && params.tolerance >= 0.0) {
        return Err(VesicleError::Parameter {
            name: "reparametrisation tolerance",
            value: params.tolerance,
            reason: "must be finite and non-negative",
        });
    }
    let p = surface.order();
    let Reparametrizer {
        sht,
        ws,
        calc,
        pe,
        gc,
        g,
        moved,
        new_coefs,
    } = plan;
    let lay = sht.layout();
    let np = sht.n_points();
    let w = weights(lay, params.weight_exponent);
    let e0 = spectral_energy(surface, params.weight_exponent);
    let mut e = e0;
    let mut iterations = 0;
    for _ in 0..params.max_iterations {
        let geom = calc.geometry(surface.coefs())?;
        for (gc, (c, w)) in gc
            .iter_mut()
            .zip(surface.coefs().iter().zip(w.iter().cycle()))
        {
            *gc = c * w;
        }
        sht.inverse(gc, g, ws)?;
        for j in 0..np {
            let gj = [g[j], g[np + j], g[2 * np + j]];
            let n = geom.normal[j];
            let gn = dot(gj, n);
            // The tangential move d = −τ P G in parameters: [E F; F G] δ = [X_θ·d; X_φ·d].
            let d: [f64; 3] = std::array::from_fn(|c| -params.step * (gj[c] - gn * n[c]));
            let (a, b) = (dot(geom.xt[j], d), dot(geom.xp[j], d));
            let gi = geom.ginv[j];
            let (t0, f0) = sht.grid().angles(j);
            let pd = pe.eval(
                lay,
                surface.coefs(),
                t0 + gi[0] * a + gi[1] * b,
                f0 + gi[1] * a + gi[2] * b,
            );
            for c in 0..3 {
                moved[c * np + j] = pd.x[c];
            }
        }
        sht.forward(moved, new_coefs, ws)?;
        let candidate = Surface::from_coefs(p, new_coefs.clone())?;
        let e_new = spectral_energy(&candidate, params.weight_exponent);
        if e_new >= e {
            break;
        }
        *surface = candidate;
        iterations += 1;
        let decrease = (e - e_new) / e;
        e = e_new;
        if decrease < params.tolerance {
            break;
        }
    }
    Ok(ReparamReport {
        energy_before: e0,
        energy_after: e,
        iterations,
    })
}
