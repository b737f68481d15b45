//! What a cell run reports (`summary.json`): per-cell observables, counters, the adaptive
//! step, and how the work was split between ranks.

use crate::fmm::gpu_near::NearDecision;
use crate::timestep::contact::ContactStats;
use crate::timestep::near_implicit::JointStats;

use serde::Serialize;

use super::error::CellRunError;
use super::partition::Reason;
use crate::comm::{spread, Communicator};
use crate::scene::cells::Effect;
use crate::scene::units::{Groups, UnitScales};
use crate::timestep::suspension::Suspension;

/// Per-cell observables at the end of the run (`summary.json`'s `per_cell`, in scene order).
#[derive(Clone, Debug, Serialize)]
pub struct CellSummary {
    /// Relative change of the area since the start of the run, `(A − A₀)/A₀` (signed). An
    /// error for an inextensible cell; for a capsule its strain (the area changes physically).
    pub area_drift: f64,
    /// Relative change of the enclosed volume since the start, `(V − V₀)/V₀` (signed).
    pub volume_drift: f64,
    /// Centroid at the end.
    pub centroid: [f64; 3],
    /// Centroid velocity over the last step: its displacement divided by the last `dt` (NaN,
    /// `null` in JSON, when this invocation stopped before the end of the run).
    pub centroid_velocity: [f64; 3],
    /// Inclination in degrees: the angle from the x axis of the cell's long axis (the axis of
    /// its smallest moment of inertia) in the x–y plane, `atan(a_y / a_x)`, in `[−90, 90]`
    /// (in shear, the angle to the flow direction in the shear plane).
    pub inclination_deg: f64,
    /// Taylor deformation `D = (L − B)/(L + B)` of the equivalent ellipsoid in the `x`–`y`
    /// plane ([`crate::vesicle::Geometry::taylor_deformation`] about `z`).
    pub taylor_deformation: f64,
    /// Tank-treading rate: the membrane's mean phase rate about the `z` axis through its
    /// centre in the last step ([`crate::vesicle::Geometry::tank_treading_rate`]), clockwise
    /// seen from `+z` (the sense of the shear `u = (γ̇y, 0, 0)`). For a cell tank-treading
    /// steadily, `2π` over the period of its material points; a rigid sphere in that shear
    /// turns at `γ̇/2`. NaN (`null`) before the first step.
    pub tank_treading_rate: f64,
}

/// What `summary.json` holds. The top-level drifts are the largest over the cells; centroid,
/// velocity and inclination are those of the mean over the cells (of cell 0 for one cell);
/// `per_cell` has every cell's.
#[derive(Clone, Debug, Serialize)]
pub struct CellRunSummary {
    /// What each packed placement achieved (`placement = "packed"`).
    pub packings: Vec<crate::scene::packing::PackingReport>,
    /// Number of cells.
    pub cells: usize,
    /// Spherical-harmonic order `p`.
    pub order: usize,
    /// Quadrature order `q = upsample · p`.
    pub upsampled_order: usize,
    /// The (first) time step.
    pub dt: f64,
    /// Steps taken (accepted steps, all invocations of a resumed run).
    pub steps: usize,
    /// Time reached.
    pub final_time: f64,
    /// Whether the run reached `t_end` (false: stopped early with a checkpoint).
    pub completed: bool,
    /// The adaptive time step's record (`null`: fixed `dt`).
    pub adaptive: Option<AdaptiveSummary>,
    /// The sum over the steps of the area/volume error estimate (the error the steps
    /// committed before the drift correction restored area and volume).
    pub area_volume_error_sum: f64,
    /// Time-integration scheme: `"euler"` or `"bdf2"`.
    pub scheme: &'static str,
    /// How the cells' coupling entered the steps: `"explicit"` or `"near_implicit"`.
    pub coupling: &'static str,
    /// The near-implicit coupling's zone in units of `R/√p` (`[numerics] implicit_zone`;
    /// `null` with the explicit coupling).
    pub implicit_zone: Option<f64>,
    /// The smallest surface gap `d_min` the contact projection keeps (`null`: no projection).
    pub contact_distance: Option<f64>,
    /// GMRES relative residual tolerance.
    pub gmres_tol: f64,
    /// Digits asked of the FMM (`null` for one cell: no FMM).
    pub fmm_digits: Option<u32>,
    /// Where the FMM's near field ran (on rank 0) and why (`null`: no FMM was built).
    pub near_field: Option<NearDecision>,
    /// What the scene builds and why ([`crate::scene::cells::effects`], plus `adaptive_dt`).
    pub effects: Vec<Effect>,
    /// Wall seconds of the time loop (setup excluded; all invocations of a resumed run).
    pub wall_s: f64,
    /// Seconds in the steps (solves, coupling, rejected tries; all invocations).
    pub step_s: f64,
    /// Seconds of the coupling on rank 0 in this invocation (quadrature setup, FMM, self
    /// subtraction, ghost exchange, near corrections; part of `step_s`).
    pub coupling_s: f64,
    /// Seconds writing frames and checkpoints, gathers included (all invocations).
    pub output_s: f64,
    /// Threads in all: rayon threads per rank times ranks.
    pub threads: usize,
    /// Throughput: `steps · cells / (step_s · threads)`.
    pub cell_steps_per_core_second: f64,
    /// GMRES iterations per cell and accepted step, averaged over the run.
    pub gmres_iterations_mean: f64,
    /// The most GMRES iterations of one cell's solve in an accepted step.
    pub gmres_iterations_max: usize,
    /// Counters of what was built (checked by the tests: a one-cell scene builds no FMM).
    pub counters: Counters,
    /// The physical scales of a scene written in SI units (`null`: the file's numbers were
    /// the solver's own); every other number here is in the solver's units.
    pub units: Option<UnitScales>,
    /// The dimensionless groups of the first cells (capillary number, reduced bending,
    /// viscosity ratio).
    pub dimensionless: Option<Groups>,
    /// The area drift of the cell whose drift is largest in magnitude (signed; see
    /// [`CellSummary::area_drift`]).
    pub area_drift: f64,
    /// The volume drift of the cell whose drift is largest in magnitude (signed).
    pub volume_drift: f64,
    /// Mean of the cells' centroids.
    pub centroid: [f64; 3],
    /// Mean of the cells' centroid velocities.
    pub centroid_velocity: [f64; 3],
    /// Mean of the cells' inclinations, in degrees.
    pub inclination_deg: f64,
    /// Smallest distance between a grid point of one cell and another cell's surface seen in
    /// the run (`null`: no point ever came within a near zone).
    pub min_gap: Option<f64>,
    /// Every cell's observables, in scene order.
    pub per_cell: Vec<CellSummary>,
    /// Frames written, the initial one included.
    pub frames: usize,
    /// How the work was split between MPI ranks (one rank: all of it on rank 0).
    pub split: SplitSummary,
}

/// What the adaptive time step did.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct AdaptiveSummary {
    /// Relative area/volume error allowed over the run.
    pub tolerance: f64,
    /// Smallest step allowed.
    pub dt_min: f64,
    /// Largest step allowed.
    pub dt_max: f64,
    /// Steps rejected (their area/volume error too large, or their solve failed) and repeated
    /// with a smaller `dt`.
    pub rejected_steps: usize,
    /// Steps accepted at `dt_min` although their error exceeded what they may commit.
    pub steps_above_tolerance: usize,
    /// Smallest step taken.
    pub dt_smallest: f64,
    /// Largest step taken.
    pub dt_largest: f64,
    /// Last step taken.
    pub dt_last: f64,
}

/// What the run built and how often (this invocation of a resumed run; `summary.json`'s
/// `counters`).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Counters {
    /// FMM trees built for the single layer between cells (one per coupling evaluation; 0
    /// for one cell).
    pub fmm_builds: usize,
    /// Point–cell pairs pushed apart by the contact repulsion.
    pub repulsion_points: usize,
    /// Double-layer operators assembled (cells with a viscosity contrast, once per step; in this
    /// invocation).
    pub double_layer_assemblies: usize,
    /// Grid points that received a near-singular correction, summed over the ranks and the
    /// coupling evaluations.
    pub near_points: usize,
    /// Ordered cell pairs (target, source) with near points, summed over the coupling
    /// evaluations.
    pub near_pairs: usize,
    /// Stresslet FMMs built for the inter-cell double layer (several cells, some `λ ≠ 1`: one
    /// per step from the second on; 0 otherwise).
    pub double_layer_fmm_builds: usize,
    /// Cells' own preconditioners built (`[numerics] preconditioner = "cell"`; in this
    /// invocation, those rebuilt from a checkpoint's records included).
    pub preconditioner_builds: usize,
    /// What the near-implicit coupling solved jointly (`[numerics] coupling =
    /// "near_implicit"`; zeros otherwise): clusters, their cells, the largest, their GMRES
    /// iterations.
    pub near_implicit: JointStats,
    /// What the contact projection did (`[numerics] contact_distance`; zeros and no gaps
    /// otherwise): steps, steps that moved cells, rounds, active contacts, cell moves, seconds
    /// (its share of the time), the last and the smallest end-of-step gap (where below
    /// `3 d_min`).
    pub contacts: ContactStats,
    /// What the rigid walls did (`[[walls]]`; zeros otherwise): walls, unknowns, setup
    /// seconds, solves, seconds, the largest wall velocity at a cell in the last step.
    pub walls: crate::timestep::wall_coupling::WallStats,
    /// What the plane wall did (`[[walls]] shape = "plane"`; `None` otherwise): evaluations of
    /// the images, seconds, point forces, the last and the smallest height of a cell's grid
    /// point above the plane.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_wall: Option<crate::timestep::plane_coupling::PlaneStats>,
    /// The start-up before the first step (`[numerics] start_up_passes`; `None` where it did
    /// not run: one cell and no walls, passes 0, or a resumed run, which continues from its
    /// checkpoint's densities): passes taken and the last pass's relative tension change.
    pub start_up: Option<crate::timestep::suspension::StartUpReport>,
    /// Cells recycled through a tube (`[flow] recycle = true`; `None` otherwise): cells moved
    /// back from the outlet, steps at which a cell could not land clear, seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recycling: Option<crate::timestep::suspension::RecycleStats>,
}

/// How the run's work was split between ranks (`summary.json`'s `split`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct SplitSummary {
    /// Number of MPI ranks.
    pub ranks: usize,
    /// Cells per rank at the end: smallest, mean, largest.
    pub cells_per_rank: [f64; 3],
    /// Seconds per rank in this invocation, largest and mean over the ranks: the per-cell
    /// work (tractions and solves, not waiting for other ranks; with re-balanced cells, its
    /// spread is the imbalance), the coupling (FMM, quadrature setup, self subtraction, ghost exchange, near
    /// corrections), output (gathers and writing), re-balancing (gathering centres, moving
    /// cells).
    pub solve_s: [f64; 2],
    /// Seconds of the coupling (all its parts), largest and mean.
    pub coupling_s: [f64; 2],
    /// Seconds in the FMM (build and evaluation), largest and mean; part of `coupling_s`.
    pub fmm_s: [f64; 2],
    /// Seconds building the FMM trees (cuts, routing of the points, lists, LET pattern),
    /// largest and mean; part of `fmm_s`.
    pub fmm_build_s: [f64; 2],
    /// Seconds of the FMM evaluations' communication, largest and mean; part of `fmm_s`.
    pub fmm_comm_s: [f64; 2],
    /// Seconds of each FMM phase (`p2m`, `m2m`, `m2l_fft`, `m2l_hadamard`, `p2l`, `l2l`,
    /// `l2p`, `m2p`, `p2p`), the largest over the ranks; part of `fmm_s` (thread-summed
    /// where the FMM's own timings are: see [`crate::fmm::FmmTimings`]).
    pub fmm_phases_max_s: std::collections::BTreeMap<String, f64>,
    /// Seconds exchanging ghost cells, largest and mean; part of `coupling_s`.
    pub ghost_exchange_s: [f64; 2],
    /// Seconds of the near-singular corrections, largest and mean; part of `coupling_s`.
    pub near_s: [f64; 2],
    /// Seconds of output (gathers and writing), largest and mean.
    pub output_s: [f64; 2],
    /// Seconds re-balancing (gathering centres, moving cells), largest and mean.
    pub rebalance_s: [f64; 2],
    /// Bytes a rank sent per step (largest and mean over ranks): in the FMM, of ghost cells,
    /// of moving cells.
    pub fmm_bytes_per_step: [f64; 2],
    /// Bytes a rank sent per step building the FMM trees (cuts, points to their owners, the
    /// LET's structure), largest and mean.
    pub fmm_setup_bytes_per_step: [f64; 2],
    /// FMM points (sources and targets) a rank sent to another rank's tree per step, largest
    /// and mean: the points of cells that straddle the tree's cuts.
    pub fmm_points_moved_per_step: [f64; 2],
    /// Bytes of ghost cells a rank sent per step, largest and mean.
    pub ghost_bytes_per_step: [f64; 2],
    /// Bytes of moving cells a rank sent per step, largest and mean.
    pub migration_bytes_per_step: [f64; 2],
    /// Ghost cells a rank received per step (largest and mean).
    pub ghost_cells_per_step: [f64; 2],
    /// Peak resident memory of a rank's process in MiB (Linux's `VmHWM`), largest and mean
    /// over the ranks; zeros where the system does not say.
    pub peak_rss_mib: [f64; 2],
    /// Imbalance of the solve time at the end: largest over mean, minus 1.
    pub solve_imbalance: f64,
    /// The re-balances of this invocation.
    pub rebalances: Vec<Rebalance>,
}

/// One re-balance: when, why, and what it did.
#[derive(Clone, Debug, Serialize)]
pub struct Rebalance {
    /// Taken before this step.
    pub step: usize,
    /// Why the cells were moved (JSON `"imbalance"` or `"locality"`).
    pub reason: Reason,
    /// Cost imbalance before (largest rank over mean, minus 1).
    pub imbalance_before: f64,
    /// Cost imbalance after, of the fresh split.
    pub imbalance_after: f64,
    /// Fraction of the cells the fresh split put on another rank.
    pub stale_fraction: f64,
    /// Cells moved to another rank.
    pub cells_moved: usize,
}

/// Per-rank counters of one invocation.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct RankClock {
    pub(super) output_s: f64,
    pub(super) rebalance_s: f64,
    pub(super) migration_bytes: u64,
}

/// The ranks' clocks and counters, gathered and summarised (collective; the summary is
/// meaningful on rank 0).
pub(super) fn split_summary(
    comm: &dyn Communicator,
    susp: &Suspension,
    clock: &RankClock,
    log: &[Rebalance],
    steps: usize,
) -> Result<SplitSummary, CellRunError> {
    let st = susp.coupling_stats().unwrap_or_default();
    let coupling = st.setup_s + st.fmm_s + st.self_s + st.exchange_s + st.near_s;
    let per_step = |v: f64| v / steps.max(1) as f64;
    let mut mine = vec![
        susp.len() as f64,
        susp.solve_seconds(),
        coupling,
        st.fmm_s,
        st.exchange_s,
        st.near_s,
        clock.output_s,
        clock.rebalance_s,
        per_step(st.fmm_bytes as f64),
        per_step(st.ghost_bytes as f64),
        per_step(clock.migration_bytes as f64),
        per_step(st.ghost_cells as f64),
        per_step(st.fmm_setup_bytes as f64),
        per_step(st.fmm_points_moved as f64),
        st.fmm_build_s,
        st.fmm_comm_s,
    ];
    // Columns 16..25: the FMM's phases; then the peak memory.
    let phases = st.fmm_phases.phases();
    mine.extend(phases.iter().map(|p| p.1));
    let rss = mine.len();
    mine.push(peak_rss_bytes().map_or(0.0, |b| b as f64 / (1u64 << 20) as f64));
    let s = spread(comm, &mine).map_err(CellRunError::Comm)?;
    let max_mean = |j: usize| [s[j].max, s[j].mean];
    let solve = max_mean(1);
    Ok(SplitSummary {
        ranks: comm.size(),
        cells_per_rank: [s[0].min, s[0].mean, s[0].max],
        solve_s: solve,
        coupling_s: max_mean(2),
        fmm_s: max_mean(3),
        ghost_exchange_s: max_mean(4),
        near_s: max_mean(5),
        output_s: max_mean(6),
        rebalance_s: max_mean(7),
        fmm_bytes_per_step: max_mean(8),
        ghost_bytes_per_step: max_mean(9),
        migration_bytes_per_step: max_mean(10),
        ghost_cells_per_step: max_mean(11),
        fmm_setup_bytes_per_step: max_mean(12),
        fmm_points_moved_per_step: max_mean(13),
        fmm_build_s: max_mean(14),
        fmm_comm_s: max_mean(15),
        fmm_phases_max_s: phases
            .iter()
            .enumerate()
            .map(|(j, (name, _))| (name.to_string(), s[16 + j].max))
            .collect(),
        peak_rss_mib: max_mean(rss),
        solve_imbalance: if solve[1] > 0.0 {
            solve[0] / solve[1] - 1.0
        } else {
            0.0
        },
        rebalances: log.to_vec(),
    })
}

/// The process's peak resident memory in bytes (`VmHWM` of `/proc/self/status`), where the
/// system gives it.
pub(super) fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The peak memory read from `/proc/self/status` against the kernel's other account of
    /// it, `getrusage`'s `ru_maxrss` (KiB on Linux); the resident memory (`VmRSS`) grows by what
    /// a new buffer touches, and the peak is at least it (the peak itself need not grow: an
    /// earlier test in this process may have reached more).
    #[test]
    #[cfg(target_os = "linux")]
    fn peak_memory_agrees_with_getrusage() {
        let rusage = || {
            let mut u: libc::rusage = unsafe { std::mem::zeroed() };
            // SAFETY: `u` is a valid rusage for the kernel to fill.
            assert_eq!(unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) }, 0);
            u.ru_maxrss as f64 * 1024.0
        };
        let resident = || {
            let status = std::fs::read_to_string("/proc/self/status").unwrap();
            let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
            line.split_whitespace()
                .nth(1)
                .unwrap()
                .parse::<f64>()
                .unwrap()
                * 1024.0
        };
        let before = resident();
        let grow = 256usize << 20;
        let buffer: Vec<u8> = (0..grow).map(|i| (i % 251) as u8).collect();
        std::hint::black_box(&buffer);
        let now = resident();
        let after = peak_rss_bytes().expect("VmHWM on Linux") as f64;
        let reference = rusage();
        // Other tests' threads allocate and free meanwhile: most of the buffer shows.
        assert!(now - before >= 0.9 * grow as f64, "VmRSS {before} -> {now}");
        assert!(after >= now, "VmHWM {after} below VmRSS {now}");
        // The two accounts are read a moment apart (other tests allocate meanwhile).
        assert!(
            (after - reference).abs() <= 0.05 * reference,
            "VmHWM {after} B, ru_maxrss {reference} B"
        );
    }
}
