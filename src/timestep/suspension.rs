//! Many cells in one flow: each cell advanced by its own semi-implicit step
//! ([`VesicleStepper`]: bending, tension and self-interaction implicit), the cells coupled
//! explicitly through the velocity their membrane tractions at `Xⁿ` induce on each other
//! ([`Coupling`]: FMM, minus each cell's own smooth quadrature, plus near-singular corrections).
//!
//! This is the splitting of Veerapaneni et al. (J. Comput. Phys. 230, 2011, §3.3) and of MOBO
//! (Rahimian et al., SC'10): per step one FMM evaluation for the inter-cell velocities, then
//! independent per-cell solves (in parallel over cells; each cell's dense operators are applied
//! serially). A scene of one cell builds no [`Coupling`] and no FMM. With BDF2 the explicit
//! inter-cell velocity is extrapolated to `X* = 2Xⁿ − Xⁿ⁻¹` as `2vⁿ − vⁿ⁻¹`; the contact
//! repulsion stays first order (a penalty acting only near contact).
//!
//! **Viscosity contrast between cells.** A cell with `λ ≠ 1` is felt by the others through its
//! single layer and its double layer `(1 − λ) D[u]` ([`Coupling::velocities_with`]). Its own
//! double layer is implicit in its step; the one the others feel takes the membrane velocity
//! `u` of the cell's previous solve ([`VesicleStepper::velocity`]: `(Xⁿ − Xⁿ⁻¹)/Δt` for Euler,
//! a first-order lag, consistent with the explicit coupling; the BDF2 derivative
//! `(3Xⁿ − 4Xⁿ⁻¹ + Xⁿ⁻²)/(2Δt)` for BDF2, which then extrapolates the whole inter-cell velocity
//! as above). The first step has no velocity yet and couples the single layers only (the
//! cells' initial velocity is not known before their first solve); the double layer enters
//! from the second step on. A restart restores the velocities
//! ([`VesicleStepper::set_velocity`]). Only what is called for: with every `λ = 1` (or one cell)
//! no double-layer density is passed and no stresslet FMM is built.

use rayon::prelude::*;

use super::coupling::{Coupling, CouplingParams, CouplingStats};
use super::semi_implicit::{ExplicitTerms, StepReport, VesicleParams, VesicleStepper};
use super::TimestepError;
use crate::vesicle::skalak::SkalakParams;

/// One cell of a suspension: its initial surface and parameters.
#[derive(Clone, Debug)]
pub struct CellSetup {
    /// Order-`p` SH coefficients (x, y, z).
    pub coefs: Vec<f64>,
    /// Step parameters of this cell (moduli, force, `dt`, …; `dt` must agree between cells).
    pub params: VesicleParams,
    /// Shear elasticity and the stress-free reference surface (coefficients).
    pub skalak: Option<(SkalakParams, Vec<f64>)>,
}

/// A failure of one cell's step.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", match .cell { Some(c) => format!("cell {c}"), None => "inter-cell coupling".to_string() })]
pub struct CellStepError {
    /// Index of the cell (`None`: the coupling).
    pub cell: Option<usize>,
    /// What went wrong.
    pub source: TimestepError,
}

/// What one step of the suspension did.
#[derive(Clone, Debug)]
pub struct SuspensionReport {
    /// Per cell: the GMRES solve.
    pub cells: Vec<StepReport>,
}

impl SuspensionReport {
    /// The largest area/volume error of a cell in this step (the adaptive-`dt` estimate) and
    /// the cell that committed it.
    pub fn area_volume_error(&self) -> (f64, usize) {
        self.cells
            .iter()
            .enumerate()
            .fold((0.0, 0), |(e, c), (i, r)| {
                // NaN wins: a failed estimate must not pass as small.
                if r.area_volume_error > e || r.area_volume_error.is_nan() && !e.is_nan() {
                    (r.area_volume_error, i)
                } else {
                    (e, c)
                }
            })
    }
}

/// Everything a step changes, kept to repeat a rejected step (adaptive `dt`).
#[derive(Clone, Debug)]
pub struct SuspensionState {
    coefs: Vec<Vec<f64>>,
    sigma: Vec<Vec<f64>>,
    previous: Vec<Option<Vec<f64>>>,
    previous_dt: Vec<Option<f64>>,
    membrane_velocities: Vec<Option<Vec<f64>>>,
    skalak_references: Vec<Option<Vec<f64>>>,
    velocities: Vec<Vec<f64>>,
    previous_velocities: Vec<Vec<f64>>,
}

/// Cells of order `p`, stepped together.
pub struct Suspension {
    steppers: Vec<VesicleStepper>,
    coefs: Vec<Vec<f64>>,
    coupling: Option<Coupling>,
    /// Inter-cell velocities of the last step (per cell, order-`p` grid), kept for output.
    velocities: Vec<Vec<f64>>,
    /// Those of the step before (BDF2 extrapolates the explicit coupling to `X*`).
    previous_velocities: Vec<Vec<f64>>,
    /// Whether the cells with `λ ≠ 1` pass their double layer to the others (on by default;
    /// switched off only to measure what it does).
    inter_cell_double_layer: bool,
}

impl Suspension {
    /// Set up the cells (all of order `p`). With two or more cells the coupling is built with
    /// `coupling` (its far-field quadrature at each cell's upsampled order); with one cell
    /// nothing is coupled and no FMM is ever built.
    pub fn new(
        p: usize,
        cells: Vec<CellSetup>,
        coupling: CouplingParams,
    ) -> Result<Self, CellStepError> {
        let mut steppers = Vec::with_capacity(cells.len());
        let mut coefs = Vec::with_capacity(cells.len());
        let dt0 = cells.first().map(|c| c.params.dt);
        for (i, c) in cells.into_iter().enumerate() {
            let err = |source| CellStepError {
                cell: Some(i),
                source,
            };
            if Some(c.params.dt) != dt0 {
                return Err(err(TimestepError::InvalidParameter {
                    name: "dt",
                    value: format!("{}", c.params.dt),
                    reason: "all cells of a suspension share one time step",
                }));
            }
            let mut st = VesicleStepper::new(p, c.params).map_err(err)?;
            if let Some((sk, reference)) = &c.skalak {
                st.set_skalak(*sk, reference).map_err(err)?;
            }
            steppers.push(st);
            coefs.push(c.coefs);
        }
        let coupling = if steppers.len() > 1 {
            let q = steppers[0].params().upsampled_order.max(p);
            Some(
                Coupling::new(p, q, coupling)
                    .map_err(|source| CellStepError { cell: None, source })?,
            )
        } else {
            None
        };
        Ok(Suspension {
            steppers,
            coefs,
            coupling,
            velocities: Vec::new(),
            previous_velocities: Vec::new(),
            inter_cell_double_layer: true,
        })
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.steppers.len()
    }

    /// Whether there are no cells.
    pub fn is_empty(&self) -> bool {
        self.steppers.is_empty()
    }

    /// Each cell's SH coefficients.
    pub fn coefs(&self) -> &[Vec<f64>] {
        &self.coefs
    }

    /// Replace the coefficients of every cell (restart).
    pub fn coefs_mut(&mut self) -> &mut [Vec<f64>] {
        &mut self.coefs
    }

    /// The per-cell steppers (tension, drift targets).
    pub fn steppers(&self) -> &[VesicleStepper] {
        &self.steppers
    }

    /// Mutable per-cell steppers (restart).
    pub fn steppers_mut(&mut self) -> &mut [VesicleStepper] {
        &mut self.steppers
    }

    /// Counters of the coupling (`None` for one cell: nothing coupled, no FMM).
    pub fn coupling_stats(&self) -> Option<CouplingStats> {
        self.coupling.as_ref().map(|c| c.stats)
    }

    /// The velocity the other cells induced on each cell in the last step.
    pub fn inter_cell_velocities(&self) -> &[Vec<f64>] {
        &self.velocities
    }

    /// The inter-cell velocities at `Xⁿ⁻¹` kept for the BDF2 extrapolation (empty for one cell or
    /// the Euler scheme before the first step).
    pub fn previous_inter_cell_velocities(&self) -> &[Vec<f64>] {
        &self.previous_velocities
    }

    /// The time step (shared by all cells).
    pub fn dt(&self) -> f64 {
        self.steppers.first().map_or(0.0, |s| s.params().dt)
    }

    /// Change the time step of every cell (adaptive `dt`).
    pub fn set_dt(&mut self, dt: f64) -> Result<(), CellStepError> {
        for (i, st) in self.steppers.iter_mut().enumerate() {
            st.set_dt(dt).map_err(|source| CellStepError {
                cell: Some(i),
                source,
            })?;
        }
        Ok(())
    }

    /// A copy of everything [`Suspension::step`] changes (the cells, their tensions, BDF2
    /// histories and relabelled Skalak references, the inter-cell velocities); [`Suspension::restore`] goes back to it.
    pub fn snapshot(&self) -> SuspensionState {
        SuspensionState {
            coefs: self.coefs.clone(),
            sigma: self.steppers.iter().map(|s| s.sigma.clone()).collect(),
            previous: self
                .steppers
                .iter()
                .map(|s| s.previous_coefs().map(|c| c.to_vec()))
                .collect(),
            previous_dt: self.steppers.iter().map(|s| s.previous_dt()).collect(),
            membrane_velocities: self
                .steppers
                .iter()
                .map(|s| s.velocity().map(|v| v.to_vec()))
                .collect(),
            skalak_references: self
                .steppers
                .iter()
                .map(|s| s.skalak_reference().map(|r| r.to_vec()))
                .collect(),
            velocities: self.velocities.clone(),
            previous_velocities: self.previous_velocities.clone(),
        }
    }

    /// Go back to a [`Suspension::snapshot`] (a rejected step). The drift targets and the
    /// preconditioners are not part of the state: a step does not change the former, and the
    /// latter depend only on the targets and `dt`.
    pub fn restore(&mut self, state: &SuspensionState) -> Result<(), CellStepError> {
        self.coefs.clone_from(&state.coefs);
        for (i, st) in self.steppers.iter_mut().enumerate() {
            let err = |source| CellStepError {
                cell: Some(i),
                source,
            };
            st.sigma.copy_from_slice(&state.sigma[i]);
            st.set_previous_coefs(state.previous[i].as_deref())
                .map_err(err)?;
            st.set_previous_dt(state.previous_dt[i]).map_err(err)?;
            st.set_velocity(state.membrane_velocities[i].as_deref())
                .map_err(err)?;
            if let Some(r) = &state.skalak_references[i] {
                st.set_skalak_reference(r).map_err(err)?;
            }
        }
        self.velocities.clone_from(&state.velocities);
        self.previous_velocities
            .clone_from(&state.previous_velocities);
        Ok(())
    }

    /// Restore the inter-cell velocities at `Xⁿ` and `Xⁿ⁻¹` (restart).
    pub fn set_inter_cell_velocities(&mut self, current: Vec<Vec<f64>>, previous: Vec<Vec<f64>>) {
        self.velocities = current;
        self.previous_velocities = previous;
    }

    /// Whether some cell has a viscosity contrast and there are other cells to feel its double
    /// layer (the inter-cell double layer is then built from the second step on).
    pub fn has_inter_cell_double_layer(&self) -> bool {
        self.inter_cell_double_layer
            && self.coupling.is_some()
            && self
                .steppers
                .iter()
                .any(|s| s.params().viscosity_ratio != 1.0)
    }

    /// Switch the inter-cell double layer off (or on again): the cells then feel only each
    /// other's single layers, as if every `λ` were 1 outside their own step. For studies and
    /// tests of what the double layer does; a physical run keeps it on.
    pub fn set_inter_cell_double_layer(&mut self, on: bool) {
        self.inter_cell_double_layer = on;
    }

    /// Advance every cell by one step in the background flow `u_inf`.
    pub fn step(
        &mut self,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    ) -> Result<SuspensionReport, CellStepError> {
        if let Some(coupling) = &mut self.coupling {
            self.previous_velocities = std::mem::take(&mut self.velocities);
            let tractions: Vec<Vec<f64>> = self
                .steppers
                .par_iter_mut()
                .zip(self.coefs.par_iter())
                .enumerate()
                .map(|(i, (st, c))| {
                    let mut f = vec![0.0; 3 * st.n_points()];
                    st.traction(c, &mut f).map_err(|source| CellStepError {
                        cell: Some(i),
                        source,
                    })?;
                    Ok(f)
                })
                .collect::<Result<_, _>>()?;
            let cref: Vec<&[f64]> = self.coefs.iter().map(|c| c.as_slice()).collect();
            let fref: Vec<&[f64]> = tractions.iter().map(|c| c.as_slice()).collect();
            // Double-layer densities (1 − λ_j) u_j from each cell's last solve (none before the
            // first step: the first step couples the single layers only).
            let scaled: Vec<Option<Vec<f64>>> = self
                .steppers
                .iter()
                .map(|st| {
                    let lambda = st.params().viscosity_ratio;
                    match st.velocity() {
                        Some(u) if lambda != 1.0 && self.inter_cell_double_layer => {
                            Some(u.iter().map(|v| (1.0 - lambda) * v).collect())
                        }
                        _ => None,
                    }
                })
                .collect();
            let dref: Vec<Option<&[f64]>> = scaled.iter().map(|d| d.as_deref()).collect();
            self.velocities = coupling
                .velocities_with(&cref, &fref, &dref)
                .map_err(|source| CellStepError { cell: None, source })?;
        }
        // BDF2 takes the explicit terms at X* = (1 + ω)Xⁿ − ωXⁿ⁻¹ (ω = Δtⁿ/Δtⁿ⁻¹):
        // v* = (1 + ω)vⁿ − ωvⁿ⁻¹ (second order; 2vⁿ − vⁿ⁻¹ at a constant step).
        let extrapolated: Vec<Vec<f64>> = self
            .steppers
            .iter()
            .enumerate()
            .map(|(i, st)| {
                match (
                    st.extrapolation_ratio(),
                    self.velocities.get(i),
                    self.previous_velocities.get(i),
                ) {
                    (Some(w), Some(v), Some(u)) => v
                        .iter()
                        .zip(u)
                        .map(|(a, b)| (1.0 + w) * a - w * b)
                        .collect(),
                    _ => Vec::new(),
                }
            })
            .collect();
        let velocities = &self.velocities;
        let repulsion = self.coupling.as_ref().and_then(|c| c.repulsion());
        let reports = self
            .steppers
            .par_iter_mut()
            .zip(self.coefs.par_iter_mut())
            .enumerate()
            .map(|(i, (st, c))| {
                let extra = ExplicitTerms {
                    velocity: if extrapolated[i].is_empty() {
                        velocities.get(i).map(|v| v.as_slice())
                    } else {
                        Some(extrapolated[i].as_slice())
                    },
                    traction: repulsion.map(|r| r[i].as_slice()),
                };
                st.step_with(c, u_inf, extra)
                    .map_err(|source| CellStepError {
                        cell: Some(i),
                        source,
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(SuspensionReport { cells: reports })
    }
}
