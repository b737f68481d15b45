//! The Ermak–McCammon step with hydrodynamic interactions.
//!
//! `Δr = D F Δt / k_BT + √(2Δt) B ξ`, `B Bᵀ = D`, `ξ` standard normal (Ermak & McCammon, J. Chem.
//! Phys. 69, 1978). In units of `D0 = k_BT/(6πηa)`: `Δr = (D0Δt/k_BT) D̃F + √(2D0Δt) B̃ξ`. The RPY
//! tensor is divergence-free, so no drift correction term appears.

use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use super::forces::ForceField;
use super::noise::{cholesky_factor, lanczos_sqrt};
use super::rpy::apply_mobility;
use super::tea_hi::{fused_rows, tea_hi_noise, FusedSums, Soa, TeaHiCoefficients, ROW_VALUES};
use super::BrownianError;
use crate::comm::{block_rows, Communicator, SerialComm};

/// How the noise (and with it the hydrodynamic coupling) is computed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NoiseModel {
    /// No hydrodynamic interactions: `D = D0 I`.
    FreeDraining,
    /// RPY drift, TEA-HI noise in one fused pass.
    TeaHi,
    /// RPY drift, exact noise by Cholesky factorisation.
    Cholesky,
    /// RPY drift, Krylov (Lanczos) square root to the given tolerance.
    Lanczos {
        /// Relative change `‖y_m − y_{m−1}‖/‖y_m‖` of successive iterates at which to stop.
        tol: f64,
        /// Most Lanczos steps (capped at `3N`).
        max_iter: usize,
    },
}

/// Physical and numerical parameters.
#[derive(Clone, Copy, Debug)]
pub struct BrownianParams {
    /// Bead radius `a`.
    pub radius: f64,
    /// Thermal energy `k_BT`.
    pub kt: f64,
    /// Solvent viscosity `η`.
    pub viscosity: f64,
    /// Time step.
    pub dt: f64,
    /// Noise model.
    pub noise: NoiseModel,
    /// Seed of the random stream.
    pub seed: u64,
}

impl BrownianParams {
    /// `D0 = k_BT/(6πηa)`.
    pub fn d0(&self) -> f64 {
        self.kt / (6.0 * std::f64::consts::PI * self.viscosity * self.radius)
    }
}

/// A bead system advanced by Ermak–McCammon steps.
pub struct BrownianSimulation {
    /// Parameters.
    pub params: BrownianParams,
    /// Bead positions.
    pub positions: Vec<[f64; 3]>,
    /// Force field.
    pub forces: ForceField,
    /// Simulated time.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    /// `ε` and `β'` of the last TEA-HI step.
    pub last_tea_hi: Option<TeaHiCoefficients>,
    rng: StdRng,
    f: Vec<[f64; 3]>,
    xi: Vec<[f64; 3]>,
    drift: Vec<[f64; 3]>,
    noise: Vec<[f64; 3]>,
    soa: (Soa, Soa, Soa),
    sums: FusedSums,
    /// This rank's rows: pair forces, then the fused pass.
    rows: Vec<f64>,
    /// Where each rank spent its time (one entry on one rank).
    pub timings: StepTimings,
    /// The TEA-HI pass on a GPU ([`BrownianSimulation::use_gpu`]); `None`: the CPU's.
    gpu: Option<super::gpu_pass::GpuPass>,
}

/// Seconds a rank spent in the steps so far, and what it sent.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepTimings {
    /// Its rows of the pair forces and of the fused pass (or of the whole step on one rank).
    pub rows_s: f64,
    /// Waiting for and exchanging the rows of the other ranks.
    pub exchange_s: f64,
    /// Bytes sent to other ranks.
    pub bytes_sent: u64,
}

impl BrownianSimulation {
    /// Run the TEA-HI pass where `choice` says ([`super::gpu_pass::choose`]; `precision`
    /// forces a GPU precision); returns where it runs and why. The CPU pass is the default.
    pub fn use_gpu(
        &mut self,
        choice: crate::gpu::GpuChoice,
        precision: Option<crate::gpu::GpuPrecision>,
    ) -> Result<crate::gpu::GpuDecision, BrownianError> {
        let (pass, decision) = super::gpu_pass::choose(choice, precision, self.positions.len())?;
        self.gpu = pass;
        Ok(decision)
    }

    /// A simulation of the given beads.
    pub fn new(
        params: BrownianParams,
        positions: Vec<[f64; 3]>,
        forces: ForceField,
    ) -> Result<Self, BrownianError> {
        if !(params.radius > 0.0 && params.kt > 0.0 && params.viscosity > 0.0 && params.dt > 0.0) {
            return Err(BrownianError::Parameter(
                "radius, kT, viscosity and dt must be positive".into(),
            ));
        }
        if positions.iter().flatten().any(|v| !v.is_finite()) {
            return Err(BrownianError::Parameter("positions must be finite".into()));
        }
        let n = positions.len();
        Ok(BrownianSimulation {
            params,
            positions,
            forces,
            time: 0.0,
            steps: 0,
            last_tea_hi: None,
            rng: StdRng::seed_from_u64(params.seed),
            f: vec![[0.0; 3]; n],
            xi: vec![[0.0; 3]; n],
            drift: vec![[0.0; 3]; n],
            noise: vec![[0.0; 3]; n],
            soa: Default::default(),
            sums: FusedSums::default(),
            rows: Vec::new(),
            timings: StepTimings::default(),
            gpu: None,
        })
    }

    /// One step.
    pub fn step(&mut self) -> Result<(), BrownianError> {
        self.step_on(&SerialComm)
    }

    /// One step with the `O(N²)` work split by rows over the ranks of `comm` (collective).
    ///
    /// Every rank holds every bead and draws the whole `ξ` from the same stream, computes the
    /// pair forces and the fused TEA-HI pass for its block of rows ([`block_rows`]), and
    /// all-gathers the rows; each row is a sequential sum over all beads, so every rank ends
    /// with the same numbers as one rank, bit for bit, whatever the rank or thread count. The
    /// Cholesky and Lanczos references are not split: every rank computes them whole.
    pub fn step_on(&mut self, comm: &dyn Communicator) -> Result<(), BrownianError> {
        let p = self.params;
        let a = p.radius;
        let d0 = p.d0();
        let n = self.positions.len();
        let mine = block_rows(n, comm.rank(), comm.size());
        let t0 = std::time::Instant::now();
        let mut exchange = std::time::Duration::ZERO;
        let bytes0 = comm.bytes_sent();
        // Pair forces of this rank's rows, everyone's gathered, then bonds and external.
        self.forces
            .pair_forces(&self.positions, mine.clone(), &mut self.f[mine.clone()]);
        if self.forces.has_pair_forces() && comm.size() > 1 {
            let all = gather_blocks(
                comm,
                self.f[mine.clone()].as_flattened(),
                3 * n,
                &mut exchange,
            )?;
            self.f.as_flattened_mut().copy_from_slice(&all);
        }
        self.forces
            .add_bonded_and_external(&self.positions, &mut self.f);
        for x in self.xi.iter_mut().flatten() {
            *x = StandardNormal.sample(&mut self.rng);
        }
        match p.noise {
            NoiseModel::FreeDraining => {
                self.drift.copy_from_slice(&self.f);
                self.noise.copy_from_slice(&self.xi);
            }
            NoiseModel::TeaHi => {
                let (pos, frc, xi) = &mut self.soa;
                pos.fill(&self.positions);
                frc.fill(&self.f);
                xi.fill(&self.xi);
                match &self.gpu {
                    Some(g) => g.rows(pos, frc, xi, a, mine, &mut self.rows)?,
                    None => fused_rows(pos, frc, xi, a, mine, &mut self.rows),
                }
                if comm.size() > 1 {
                    self.rows = gather_blocks(comm, &self.rows, ROW_VALUES * n, &mut exchange)?;
                }
                self.sums.fill_from_rows(&self.rows);
                let coef = TeaHiCoefficients::from_entry_sum(self.sums.entry_sum, n).ok_or(
                    BrownianError::TeaHiBreakdown {
                        step: self.steps,
                        epsilon: self.sums.entry_sum / (9.0 * (n * (n - 1)) as f64),
                    },
                )?;
                self.last_tea_hi = Some(coef);
                self.drift.copy_from_slice(&self.sums.drift);
                tea_hi_noise(&self.sums, xi, coef, &mut self.noise);
            }
            NoiseModel::Cholesky => {
                apply_mobility(&self.positions, a, &self.f, &mut self.drift);
                let l = cholesky_factor(&self.positions, a)?;
                let n3 = 3 * self.positions.len();
                for r in 0..n3 {
                    let mut s = 0.0;
                    for c in 0..=r {
                        s += l[(r, c)] * self.xi[c / 3][c % 3];
                    }
                    self.noise[r / 3][r % 3] = s;
                }
            }
            NoiseModel::Lanczos { tol, max_iter } => {
                apply_mobility(&self.positions, a, &self.f, &mut self.drift);
                self.noise = lanczos_sqrt(&self.positions, a, &self.xi, tol, max_iter)?.value;
            }
        }
        let cd = d0 * p.dt / p.kt;
        let cn = (2.0 * d0 * p.dt).sqrt();
        for ((x, d), w) in self.positions.iter_mut().zip(&self.drift).zip(&self.noise) {
            for k in 0..3 {
                x[k] += cd * d[k] + cn * w[k];
            }
        }
        if let Some(i) = self
            .positions
            .iter()
            .position(|x| !x.iter().all(|v| v.is_finite()))
        {
            return Err(BrownianError::NonFinite {
                step: self.steps,
                particle: i,
            });
        }
        self.steps += 1;
        self.time += p.dt;
        self.timings.rows_s += (t0.elapsed() - exchange).as_secs_f64();
        self.timings.exchange_s += exchange.as_secs_f64();
        self.timings.bytes_sent += comm.bytes_sent() - bytes0;
        Ok(())
    }
}

/// Every rank's block of rows, concatenated in rank order (collective): `len` values in all,
/// or an error if the ranks did not run the same step. The time spent is added to `waited`.
fn gather_blocks(
    comm: &dyn Communicator,
    local: &[f64],
    len: usize,
    waited: &mut std::time::Duration,
) -> Result<Vec<f64>, BrownianError> {
    let t = std::time::Instant::now();
    let all = comm.all_gather_f64(local)?;
    *waited += t.elapsed();
    let got: usize = all.iter().map(Vec::len).sum();
    if got == len {
        Ok(all.concat())
    } else {
        Err(BrownianError::Comm(crate::comm::CommError::Ranks {
            what: "gathered Brownian rows",
            got,
            ranks: all.len(),
        }))
    }
}
