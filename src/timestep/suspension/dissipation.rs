//! The cells' extra dissipation in a background flow, by the reciprocal theorem: the rheology
//! of a suspension (its effective viscosity in shear, the apparent viscosity of blood in a
//! tube) from quantities every cell already has.
//!
//! Let `(u₀, σ₀)` be the background flow without cells (a Stokes flow of viscosity `μ` that
//! meets the same walls), and `(u, σ)` the flow with them. Lorentz's reciprocal theorem in the
//! fluid outside the cells, and again inside each cell (whose fluid has viscosity `λμ`, so that
//! `σ_in/λ` is a stress of viscosity `μ`), gives for the power `P` the walls (or the far field)
//! put into the fluid
//!
//! ```text
//!     P − P₀ = Σ_cells ∫ [ −u₀ · f  −  (1 − λ) u · (σ₀ n) ] dA,
//! ```
//!
//! with `f` the force density the membrane exerts on the fluid (the single layer's density:
//! `−(σ_out − σ_in) n`), `u` the membrane's velocity and `n` its outward normal (Pozrikidis,
//! *Boundary Integral and Singularity Methods*, 1992, §§ 2.3 and 5.1; Batchelor, J. Fluid Mech.
//! 41, 1970, for the same integrand as the particle stresslet). A constant pressure in `σ₀`
//! drops out because a cell keeps its volume (`∫ u · n = 0`).
//!
//! * In a linear flow `u₀ = (E + Ω) x` the integral is `S : E`, the stresslet contracted with
//!   the rate of strain: in simple shear of rate `γ̇`, `(P − P₀)/(μ γ̇² V)` is the intrinsic
//!   viscosity of one cell of volume `V`, Einstein's `5/2` for a rigid sphere.
//! * In a tube carrying Poiseuille's flow of centreline speed `U` (flow rate `Q = πR²U/2`,
//!   pressure gradient `G = 4μU/R²`), `P − P₀ = ΔP⁺ Q`: the extra pressure drop the cells
//!   cause, so that the cells in a length `L` of tube raise its apparent viscosity to
//!   `μ_app/μ = 1 + (P − P₀)/(Q G L)` (Pries et al.'s relative apparent viscosity).

use super::super::TimestepError;
use super::{CellStepError, Suspension};
use crate::comm::Communicator;

impl Suspension {
    /// `P − P₀` (module docs): the cells' extra dissipation in the background flow of velocity
    /// `u0` and stress `sigma0` (a pressure constant may be left out), at their surfaces and
    /// tensions after the last step, summed over every rank in the order of the cells' global
    /// indices (collective: the same sum on any number of ranks); `None` before the first step
    /// (no membrane velocity yet).
    pub fn extra_dissipation(
        &self,
        comm: &dyn Communicator,
        u0: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        sigma0: &(dyn Fn([f64; 3]) -> [[f64; 3]; 3] + Sync),
    ) -> Result<Option<f64>, CellStepError> {
        // (global index, the cell's integral) of the cells held here.
        let mut local = Vec::with_capacity(2 * self.cells.len());
        for c in &self.cells {
            let fail = |source| CellStepError {
                cell: Some(c.id),
                source,
            };
            let Some(u) = c.state.membrane_velocity.as_deref() else {
                continue;
            };
            let n = c.stepper.n_points();
            let mut f = vec![0.0; 3 * n];
            c.stepper.traction(&c.state, &mut f).map_err(fail)?;
            let contrast = 1.0 - c.stepper.params().viscosity_ratio;
            let d = c
                .stepper
                .with_geometry(&c.state.coefs, |g| {
                    (0..n)
                        .map(|j| {
                            let x = g.x[j];
                            let (a, nm) = (u0(x), g.normal[j]);
                            let s = sigma0(x);
                            let sn: [f64; 3] =
                                std::array::from_fn(|i| (0..3).map(|k| s[i][k] * nm[k]).sum());
                            let (mut work, mut stress) = (0.0, 0.0);
                            for d in 0..3 {
                                work += a[d] * f[d * n + j];
                                stress += u[d * n + j] * sn[d];
                            }
                            (-work - contrast * stress) * g.da[j]
                        })
                        .sum::<f64>()
                })
                .map_err(fail)?;
            local.extend([c.id as f64, d]);
        }
        let gathered = comm.all_gather_f64(&local).map_err(|e| CellStepError {
            cell: None,
            source: TimestepError::Comm(e),
        })?;
        let mut all: Vec<(usize, f64)> = gathered
            .iter()
            .flat_map(|part| part.chunks_exact(2).map(|v| (v[0] as usize, v[1])))
            .collect();
        if all.is_empty() {
            return Ok(None);
        }
        all.sort_by_key(|a| a.0);
        Ok(Some(all.iter().map(|a| a.1).sum()))
    }
}
