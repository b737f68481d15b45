//! Running a Brownian scene: steps, saved frames, observables and a summary.
//!
//! Writes into the output directory (each file atomically):
//! * `trajectory.npy`: `(frames, N, 3)` positions, frame 0 the initial state;
//! * `observables.csv`: per frame `t, com_x, com_y, com_z, rg2, ree2, u_x, u_y, u_z` (`u` the
//!   end-to-end unit vector);
//! * `summary.json`: the effects enabled and why, settings, timings and averaged observables.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::brownian::observables::{
    autocorrelation, center_of_mass, end_to_end, mean_square_displacement, orientation,
    radius_of_gyration_sq,
};
use crate::brownian::{BrownianError, BrownianSimulation, NoiseModel};
use crate::comm::{agreed, block_rows, spread, CommError, Communicator, SerialComm};
use crate::gpu::GpuDecision;
use crate::io::{npy, write_atomic, IoError};
use crate::scene::brownian::BrownianScene;

/// Errors of a run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The dynamics failed.
    #[error("{0}")]
    Dynamics(#[from] BrownianError),
    /// Output could not be written.
    #[error("{0}")]
    Io(#[from] IoError),
    /// Another rank failed, or the ranks could not communicate.
    #[error("{0}")]
    Comm(#[from] CommError),
}

/// One effect the run builds, with the reason.
#[derive(Clone, Debug, Serialize)]
pub struct Effect {
    /// Effect name.
    pub name: &'static str,
    /// Built or not.
    pub enabled: bool,
    /// Why.
    pub reason: String,
}

/// What `summary.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct BrownianSummary {
    /// `[brownian.system] kind` as written (`"dimer"`, `"chain"`, `"positions"`, `"random"`).
    pub kind: String,
    /// Number of beads `N`.
    pub beads: usize,
    /// Steps taken (`[brownian] steps`).
    pub steps: u64,
    /// Time step.
    pub dt: f64,
    /// Time reached, `steps · dt`.
    pub final_time: f64,
    /// Single-bead diffusion coefficient `D0 = kT / (6πηa)`.
    pub d0: f64,
    /// The noise model, as Rust writes it (`"TeaHi"`, `"Cholesky"`, `"Lanczos { tol: …,
    /// max_iter: … }"`, `"FreeDraining"`).
    pub noise: String,
    /// Seed of the random numbers (`[brownian] seed`; default 0).
    pub seed: u64,
    /// The effects built and why ([`effects`]).
    pub effects: Vec<Effect>,
    /// Wall-clock seconds of the time loop (output excluded).
    pub wall_s: f64,
    /// Steps per wall-clock second of the time loop.
    pub steps_per_second: f64,
    /// Frames saved, the initial state included (`1 + steps / save_every`).
    pub frames: usize,
    /// Mean squared COM displacement between consecutive frames over `6 Δt_frame`: the COM
    /// diffusion coefficient when no external force acts.
    pub com_diffusion_estimate: f64,
    /// Squared radius of gyration `R_g²` averaged over the frames (the initial one included).
    pub mean_rg2: f64,
    /// Squared end-to-end distance `|x_{N−1} − x_0|²` averaged over the frames.
    pub mean_end_to_end_sq: f64,
    /// `⟨u(t)·u(0)⟩` at lags of 1, 10 and 100 frames (NaN when the run is shorter).
    pub orientation_correlation: [f64; 3],
    /// TEA-HI mean off-diagonal coupling `ε` of the last step (`null`: other noise).
    pub tea_hi_epsilon: Option<f64>,
    /// TEA-HI `β'` of the last step (`null`: other noise).
    pub tea_hi_beta: Option<f64>,
    /// How the rows were split over MPI ranks (`None` on one rank).
    pub split: Option<BrownianSplit>,
    /// Where the TEA-HI pass ran (on rank 0) and why (`null`: no TEA-HI noise).
    pub pair_pass: Option<GpuDecision>,
}

/// How a run over `K` ranks split its work: each rank its block of rows of the pair forces
/// and of the fused TEA-HI pass ([`BrownianSimulation::step_on`]).
#[derive(Clone, Debug, Serialize)]
pub struct BrownianSplit {
    /// Number of MPI ranks `K`.
    pub ranks: usize,
    /// Rows per rank, min and max.
    pub rows_per_rank: [usize; 2],
    /// Seconds in the rank's own rows (forces, fused pass, update), max and mean over ranks.
    pub rows_s: [f64; 2],
    /// Seconds exchanging (and waiting for) the other ranks' rows, max and mean.
    pub exchange_s: [f64; 2],
    /// Bytes a rank sends per step, max over ranks.
    pub bytes_per_step: f64,
    /// Whether the noise model splits over ranks (Cholesky and Lanczos run whole on each).
    pub noise_split: bool,
}

/// The effects a scene calls for, each with its reason.
pub fn effects(scene: &BrownianScene) -> Vec<Effect> {
    let n = scene.positions.len();
    let hi = !matches!(scene.params.noise, NoiseModel::FreeDraining) && n > 1;
    let ff = &scene.forces;
    vec![
        Effect {
            name: "hydrodynamic interactions (RPY)",
            enabled: hi,
            reason: if n < 2 {
                "a single bead has no partner to couple to".into()
            } else if hi {
                format!("noise = {:?} couples the beads", scene.params.noise)
            } else {
                "noise = free-draining".into()
            },
        },
        Effect {
            name: "bonds",
            enabled: !ff.bonds.is_empty() && ff.bond_stiffness > 0.0,
            reason: format!("{} bonds, stiffness {}", ff.bonds.len(), ff.bond_stiffness),
        },
        Effect {
            name: "overlap repulsion",
            enabled: ff.repulsion > 0.0 && n > 1,
            reason: format!("repulsion = {}", ff.repulsion),
        },
        Effect {
            name: "sub-cellular-element potential",
            enabled: ff.sce.is_some() && n > 1,
            reason: if ff.sce.is_some() {
                "[brownian.sce] given".into()
            } else {
                "no [brownian.sce] section".into()
            },
        },
        Effect {
            name: "external force",
            enabled: ff.external != [0.0; 3],
            reason: format!("external_force = {:?}", ff.external),
        },
    ]
}

/// Run a scene, writing results to `out`.
pub fn run(scene: &BrownianScene, out: &Path, progress: bool) -> Result<BrownianSummary, RunError> {
    run_on(&SerialComm, scene, out, progress)
}

/// Run a scene over the ranks of `comm` (collective): every rank steps every bead with its
/// block of the `O(N²)` rows ([`BrownianSimulation::step_on`]), so the trajectory is the one
/// rank's for the same seed, bit for bit; rank 0 writes the files. Every rank returns the
/// summary, or the same error.
pub fn run_on(
    comm: &dyn Communicator,
    scene: &BrownianScene,
    out: &Path,
    progress: bool,
) -> Result<BrownianSummary, RunError> {
    let root = comm.rank() == 0;
    let mut sim =
        BrownianSimulation::new(scene.params, scene.positions.clone(), scene.forces.clone())?;
    let n = sim.positions.len();
    let pair_pass = match scene.params.noise {
        NoiseModel::TeaHi => Some(sim.use_gpu(scene.gpu, None)?),
        _ => None,
    };
    let mut obs = Observed::default();
    obs.record(&sim, root);
    let bar = if progress && root {
        let b = ProgressBar::new(scene.steps);
        b.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:40}] step {pos}/{len} ({per_sec}, eta {eta}) {msg}",
            )
            .expect("static template")
            .progress_chars("=> "),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let start = Instant::now();
    for s in 1..=scene.steps {
        sim.step_on(comm)?;
        if s % scene.save_every == 0 {
            obs.record(&sim, root);
            bar.set_position(s);
            bar.set_message(format!("t = {:.4}", sim.time));
        }
    }
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    let split = split_summary(comm, &sim, scene.steps)?;
    let nf = obs.times.len();
    let frame_dt = scene.params.dt * scene.save_every as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let summary = BrownianSummary {
        kind: scene.kind.clone(),
        beads: n,
        steps: scene.steps,
        dt: scene.params.dt,
        final_time: sim.time,
        d0: scene.params.d0(),
        noise: format!("{:?}", scene.params.noise),
        seed: scene.params.seed,
        effects: effects(scene),
        wall_s: wall,
        steps_per_second: scene.steps as f64 / wall.max(1e-12),
        frames: nf,
        com_diffusion_estimate: mean_square_displacement(&obs.com, 1) / (6.0 * frame_dt),
        mean_rg2: mean(&obs.rg2),
        mean_end_to_end_sq: mean(&obs.ree2),
        orientation_correlation: [
            autocorrelation(&obs.u, 1),
            autocorrelation(&obs.u, 10),
            autocorrelation(&obs.u, 100),
        ],
        tea_hi_epsilon: sim.last_tea_hi.map(|c| c.epsilon),
        tea_hi_beta: sim.last_tea_hi.map(|c| c.beta),
        split,
        pair_pass,
    };
    // Rank 0 writes every file; the others learn whether it could.
    let written = if root {
        obs.write(out, n).and_then(|()| {
            let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
            Ok(write_atomic(&out.join("summary.json"), json.as_bytes())?)
        })
    } else {
        Ok(())
    };
    agreed(comm, written, RunError::Comm)?;
    Ok(summary)
}

/// The split of a run over more than one rank (collective).
fn split_summary(
    comm: &dyn Communicator,
    sim: &BrownianSimulation,
    steps: u64,
) -> Result<Option<BrownianSplit>, RunError> {
    let k = comm.size();
    if k == 1 {
        return Ok(None);
    }
    let t = sim.timings;
    let n = sim.positions.len();
    let rows = block_rows(n, comm.rank(), k).len() as f64;
    let s = spread(comm, &[rows, t.rows_s, t.exchange_s, t.bytes_sent as f64])?;
    Ok(Some(BrownianSplit {
        ranks: k,
        rows_per_rank: [s[0].min as usize, s[0].max as usize],
        rows_s: [s[1].max, s[1].mean],
        exchange_s: [s[2].max, s[2].mean],
        bytes_per_step: s[3].max / steps.max(1) as f64,
        noise_split: matches!(
            sim.params.noise,
            NoiseModel::TeaHi | NoiseModel::FreeDraining
        ),
    }))
}

/// The saved frames and the observables of each.
#[derive(Default)]
struct Observed {
    /// Positions of every frame (kept where the files are written).
    frames: Vec<f64>,
    times: Vec<f64>,
    com: Vec<[f64; 3]>,
    /// End-to-end unit vectors.
    u: Vec<[f64; 3]>,
    rg2: Vec<f64>,
    ree2: Vec<f64>,
}

impl Observed {
    fn record(&mut self, sim: &BrownianSimulation, keep_positions: bool) {
        if keep_positions {
            self.frames.extend(sim.positions.iter().flatten());
        }
        self.times.push(sim.time);
        self.com.push(center_of_mass(&sim.positions));
        self.rg2.push(radius_of_gyration_sq(&sim.positions));
        let e = end_to_end(&sim.positions);
        self.ree2.push(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
        self.u.push(if sim.positions.len() > 1 {
            orientation(&sim.positions)
        } else {
            [0.0; 3]
        });
    }

    /// `trajectory.npy` and `observables.csv` (atomically).
    fn write(&self, out: &Path, n: usize) -> Result<(), RunError> {
        let nf = self.times.len();
        npy::write_f64(&out.join("trajectory.npy"), &[nf, n, 3], &self.frames)?;
        let mut csv = String::from("t,com_x,com_y,com_z,rg2,ree2,u_x,u_y,u_z\n");
        for f in 0..nf {
            let (c, o) = (self.com[f], self.u[f]);
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{},{},{}",
                self.times[f], c[0], c[1], c[2], self.rg2[f], self.ree2[f], o[0], o[1], o[2]
            );
        }
        write_atomic(&out.join("observables.csv"), csv.as_bytes())?;
        Ok(())
    }
}
