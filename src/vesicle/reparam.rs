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
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

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
    /// Parameters `(θ, φ)` each grid point moves to in the current move.
    shifts: Vec<(f64, f64)>,
    /// The basis at the shifted parameters (`n_p × n_c`, row-major: row `j` the basis
    /// functions at `shifts[j]`), built once per move and shared by the surface and every
    /// passenger relabelled by it.
    basis: Vec<f64>,
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
            shifts: vec![(0.0, 0.0); np],
            basis: vec![0.0; np * nc],
            sht,
        })
    }

    /// The order the transforms were planned for.
    pub fn order(&self) -> usize {
        self.sht.order()
    }

    fn check_order(&self, surface: &Surface) -> Result<(), VesicleError> {
        if surface.order() != self.sht.order() {
            return Err(VesicleError::Parameter {
                name: "surface order",
                value: surface.order() as f64,
                reason: "differs from the order the reparametrisation was planned for",
            });
        }
        Ok(())
    }

    /// Reparametrise `surface` (of this order) in place (see the module docs).
    pub fn run(
        &mut self,
        surface: &mut Surface,
        params: &ReparamParams,
    ) -> Result<ReparamReport, VesicleError> {
        self.run_with(surface, params, &mut [])
    }

    /// [`Self::run`], relabelling every passenger the same way (see `relabel`): the
    /// stress-free reference of an elastic membrane, the surface of the previous step, fields
    /// on the surface given by their coefficients. Each passenger holds `3 (p+1)²` coefficients
    /// (three functions; pad a scalar field with zeros).
    pub fn run_with(
        &mut self,
        surface: &mut Surface,
        params: &ReparamParams,
        passengers: &mut [&mut [f64]],
    ) -> Result<ReparamReport, VesicleError> {
        self.check_order(surface)?;
        self.check_passengers(passengers)?;
        reparametrize_with(self, surface, params, passengers)
    }

    fn check_passengers(&self, passengers: &[&mut [f64]]) -> Result<(), VesicleError> {
        for p in passengers {
            super::check_len(
                "reparametrisation passenger",
                p.len(),
                3 * self.sht.n_coefs(),
            )?;
        }
        Ok(())
    }

    /// The basis at the parameters of the current move (`shifts`) into `basis`.
    fn build_basis(&mut self) {
        let lay = self.sht.layout();
        let nc = lay.len();
        for (&(t, f), row) in self.shifts.iter().zip(self.basis.chunks_exact_mut(nc)) {
            self.pe.basis_row(lay, t, f, row);
        }
    }

    /// Relabel three functions given by their coefficients `coefs` by the parameter map of the
    /// last move: `c ← F[c(θ_j + δθ_j, φ_j + δφ_j)]` (point evaluation through the move's
    /// basis, one product for the three functions, then the forward transform). A surface
    /// relabelled so is the same surface with its grid points moved; a material field
    /// (reference shape, tension, velocity) stays attached to the material.
    fn relabel(&mut self, coefs: &mut [f64]) -> Result<(), VesicleError> {
        let np = self.sht.n_points();
        let nc = self.sht.n_coefs();
        matmul(
            MatMut::from_column_major_slice_mut(&mut self.moved, np, 3),
            Accum::Replace,
            MatRef::from_row_major_slice(&self.basis, np, nc),
            MatRef::from_column_major_slice(coefs, nc, 3),
            1.0,
            Par::Seq,
        );
        self.sht
            .forward(&self.moved, &mut self.new_coefs, &mut self.ws)?;
        coefs.copy_from_slice(&self.new_coefs);
        Ok(())
    }
}

/// The parameters `(θ_j + δθ, φ_j + δφ)` of the point reached from grid point `j` by the
/// tangent move `d`: one Gauss–Newton step, `[E F; F G] δ = [X_θ·d; X_φ·d]`.
fn parameter_shift(
    sht: &ShTransform,
    geom: &super::geometry::Geometry,
    j: usize,
    d: [f64; 3],
) -> (f64, f64) {
    let (a, b) = (dot(geom.xt[j], d), dot(geom.xp[j], d));
    let gi = geom.ginv[j];
    let (t0, f0) = sht.grid().angles(j);
    (t0 + gi[0] * a + gi[1] * b, f0 + gi[1] * a + gi[2] * b)
}

fn reparametrize_with(
    plan: &mut Reparametrizer,
    surface: &mut Surface,
    params: &ReparamParams,
    passengers: &mut [&mut [f64]],
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
    let np = plan.sht.n_points();
    let w = weights(plan.sht.layout(), params.weight_exponent);
    let e0 = spectral_energy(surface, params.weight_exponent);
    let mut e = e0;
    let mut iterations = 0;
    let mut candidate = surface.coefs().to_vec();
    for _ in 0..params.max_iterations {
        let geom = plan.calc.geometry(surface.coefs())?;
        for (gc, (c, w)) in plan
            .gc
            .iter_mut()
            .zip(surface.coefs().iter().zip(w.iter().cycle()))
        {
            *gc = c * w;
        }
        plan.sht.inverse(&plan.gc, &mut plan.g, &mut plan.ws)?;
        for j in 0..np {
            let gj = [plan.g[j], plan.g[np + j], plan.g[2 * np + j]];
            let n = geom.normal[j];
            let gn = dot(gj, n);
            // The tangential move d = −τ P G.
            let d: [f64; 3] = std::array::from_fn(|c| -params.step * (gj[c] - gn * n[c]));
            plan.shifts[j] = parameter_shift(&plan.sht, &geom, j, d);
        }
        plan.build_basis();
        candidate.copy_from_slice(surface.coefs());
        plan.relabel(&mut candidate)?;
        let candidate_surface = Surface::from_coefs(p, candidate.clone())?;
        let e_new = spectral_energy(&candidate_surface, params.weight_exponent);
        if e_new >= e {
            break;
        }
        *surface = candidate_surface;
        for q in passengers.iter_mut() {
            plan.relabel(q)?;
        }
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

#[cfg(test)]
mod relabel_tests {
    use super::*;

    /// A relabelling through the move's basis (one product for the three functions) equals
    /// point evaluation at each shifted parameter followed by the forward transform, to
    /// round-off.
    #[test]
    fn relabel_by_the_basis_equals_point_evaluation() {
        for p in [6usize, 12] {
            let mut plan = Reparametrizer::new(p).unwrap();
            let (nc, np) = (plan.sht.n_coefs(), plan.sht.n_points());
            let mut s = 11u64;
            let mut rnd = || {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            };
            let coefs: Vec<f64> = (0..3 * nc).map(|_| rnd()).collect();
            for j in 0..np {
                let (t, f) = plan.sht.grid().angles(j);
                plan.shifts[j] = (t + 0.05 * rnd(), f + 0.05 * rnd());
            }
            plan.build_basis();
            let mut by_basis = coefs.clone();
            plan.relabel(&mut by_basis).unwrap();
            let lay = plan.sht.layout().clone();
            let mut moved = vec![0.0; 3 * np];
            for j in 0..np {
                let (t, f) = plan.shifts[j];
                let x = plan.pe.eval_values(&lay, &coefs, t, f);
                for c in 0..3 {
                    moved[c * np + j] = x[c];
                }
            }
            let mut by_points = vec![0.0; 3 * nc];
            let mut ws = plan.sht.workspace();
            plan.sht.forward(&moved, &mut by_points, &mut ws).unwrap();
            crate::check::assert_close(
                &format!("p = {p}: relabelling by the basis against point evaluation"),
                &by_basis,
                &by_points,
                // A sum of n_c products, then the forward transform: round-off of order n_c ε.
                8.0 * nc as f64 * f64::EPSILON,
            );
        }
    }
}
