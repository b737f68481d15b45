//! `mobo fmm`: an N-body sum on user data, on one rank or under `mpirun`.
//!
//! Under `mpirun -n K` (with the `mpi` feature), rank `r` reads rows
//! `[r·n/K, (r+1)·n/K)` of each input file (never the whole file), the FMM runs over the K
//! ranks, rank 0 gathers the values and writes the same `.npy` as one rank would, and the JSON
//! line adds the ranks, the points each rank owns after the partition, the load imbalance and
//! the bytes each rank sent. A bad file on any rank ends every rank with one message.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

use mobo::comm::{CommError, Communicator, SerialComm};
use mobo::fmm::gpu_near::{choose, gpu_expected, GPU_LEAF_FACTOR};
use mobo::fmm::{order_for_digits, Fmm, FmmError, FmmKernel};
use mobo::gpu::{GpuChoice, GpuPrecision};

use crate::cli_error::CliError;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum KernelArg {
    Laplace,
    LaplaceDl,
    Stokeslet,
    Stresslet,
    Rpy,
}

/// Arguments of `mobo fmm`.
#[derive(clap::Args)]
pub struct FmmArgs {
    /// Kernel.
    #[arg(long, value_enum)]
    kernel: KernelArg,
    /// Source points, shape (N, 3).
    #[arg(long)]
    sources: PathBuf,
    /// Densities: (N,) or (N, 1) for Laplace charges, (N, 3) for vector kernels.
    #[arg(long)]
    density: PathBuf,
    /// Target points, shape (M, 3) (default: the sources, self terms left out except RPY's).
    #[arg(long)]
    targets: Option<PathBuf>,
    /// Source normals / orientations, shape (N, 3) (stresslet, laplace-dl).
    #[arg(long)]
    normals: Option<PathBuf>,
    /// Bead radius (rpy).
    #[arg(long)]
    radius: Option<f64>,
    /// Requested accuracy in digits (3 to 10).
    #[arg(long, default_value_t = 6)]
    digits: u32,
    /// FMM order (surface points per box edge, 2 to 20); overrides the order that --digits
    /// selects from the calibration table.
    #[arg(long)]
    order: Option<usize>,
    /// Maximum points per leaf box, sources plus targets (default: chosen from kernel and
    /// order; 4× larger where the near field goes to a GPU; √2 larger for Laplace without
    /// --targets, where on one rank the near field evaluates each pair once for both
    /// directions).
    #[arg(long)]
    leaf_size: Option<usize>,
    /// Exact direct summation instead of the FMM (one rank only).
    #[arg(long)]
    direct: bool,
    /// Near field on the GPU: `--gpu` (or `--gpu true`) uses it or fails with the reason,
    /// `--gpu auto` where an adapter exists, serves the digits and the problem is large enough
    /// to gain; `--gpu false` (the default) keeps the CPU. The JSON line says which and why.
    #[arg(long, value_name = "auto|true|false", num_args = 0..=1, default_missing_value = "true", default_value = "false")]
    gpu: String,
    /// Precision of the GPU kernels (default: f64 where the adapter has it, else f32).
    #[arg(long, value_name = "f32|f64")]
    gpu_precision: Option<String>,
    /// Evaluate this many times on the same tree (the JSON's eval_s is the fastest,
    /// eval_first_s the first: GPU pipelines are compiled on first use).
    #[arg(long, default_value_t = 1)]
    repeat: usize,
    /// Compute the translation operators' fits instead of loading them from (and storing
    /// them in) the operator cache (`MOBO_OPERATOR_CACHE`, default `~/.cache/mobo/operators`;
    /// the JSON's `operator_cache` names the directory used).
    #[arg(long)]
    no_cache: bool,
    /// The most memory (MiB) the M2L's frequency-domain buffers of one tree level may take; a
    /// level that needs more runs in parts (slower: sources near a split are transformed once
    /// per part). The JSON's `m2l_buffer_peak_mib` is what the evaluation used.
    #[arg(long, default_value_t = (mobo::fmm::evaluator::M2L_BUFFER_BYTES >> 20) as u64)]
    m2l_buffer_mib: u64,
    /// Output file, (M,) for Laplace kernels, (M, 3) for vector kernels.
    #[arg(long)]
    out: PathBuf,
}

/// The ranks of this process: MPI's world under `mpirun` (with the `mpi` feature), else one.
pub(crate) fn world() -> Box<dyn Communicator> {
    #[cfg(feature = "mpi")]
    {
        let launched = ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"]
            .iter()
            .any(|v| std::env::var_os(v).is_some());
        if launched {
            if let Some(c) = mobo::comm::MpiComm::init() {
                return Box::new(c);
            }
        }
    }
    Box::new(SerialComm)
}

/// This rank's block of the `n` rows ([`mobo::comm::block_rows`]).
fn my_rows(n: usize, comm: &dyn Communicator) -> Range<usize> {
    mobo::comm::block_rows(n, comm.rank(), comm.size())
}

/// This rank's rows of an `.npy` array of `rows × cols` finite values (`cols = 1` also
/// accepts shape `(rows,)`); `expect = None` takes any row count. Errors name the file and the
/// global row.
fn read_share(
    path: &Path,
    cols: usize,
    expect: Option<usize>,
    comm: &dyn Communicator,
) -> Result<(usize, Vec<f64>), String> {
    let bad = |m: String| format!("{}: {m}", path.display());
    // The header first (rows 0..0), then this rank's rows.
    let (shape, _) = mobo::io::npy::read_f64_rows(path, 0..0).map_err(|e| e.to_string())?;
    let rows = match shape.as_slice() {
        [r] if cols == 1 => *r,
        [r, c] if *c == cols => *r,
        _ => {
            let want = if cols == 1 {
                "(N,) or (N, 1)".to_string()
            } else {
                format!("(N, {cols})")
            };
            return Err(bad(format!("shape {shape:?}, expected {want}")));
        }
    };
    if let Some(n) = expect {
        if rows != n {
            return Err(bad(format!("{rows} rows, but there are {n} sources")));
        }
    }
    let mine = my_rows(rows, comm);
    let (_, data) = mobo::io::npy::read_f64_rows(path, mine.clone()).map_err(|e| e.to_string())?;
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!(
            "non-finite value {} at row {}",
            data[i],
            mine.start + i / cols
        )));
    }
    Ok((rows, data))
}

fn points(v: Vec<f64>) -> Vec<[f64; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// The kernel and order the arguments ask for (the same on every rank).
fn settings(a: &FmmArgs) -> Result<(FmmKernel, usize, usize, GpuChoice), CliError> {
    if !(3..=10).contains(&a.digits) {
        return Err(CliError::Arg(format!(
            "--digits must be between 3 and 10, got {}",
            a.digits
        )));
    }
    let name = match a.kernel {
        KernelArg::Laplace => "laplace",
        KernelArg::LaplaceDl => "laplace-dl",
        KernelArg::Stokeslet => "stokeslet",
        KernelArg::Stresslet => "stresslet",
        KernelArg::Rpy => {
            let r = a
                .radius
                .ok_or_else(|| CliError::Arg("--radius is required for --kernel rpy".into()))?;
            if !(r.is_finite() && r > 0.0) {
                return Err(CliError::Arg(format!("--radius must be positive, got {r}")));
            }
            "rpy"
        }
    };
    let kind = FmmKernel::from_name(name, a.radius)?;
    let order = match a.order {
        Some(p) if !(2..=20).contains(&p) => {
            return Err(CliError::Arg(format!(
                "--order must be between 2 and 20, got {p}"
            )))
        }
        Some(p) => p,
        None => order_for_digits(kind, a.digits)?,
    };
    let gpu = GpuChoice::parse(&a.gpu).ok_or_else(|| {
        CliError::Arg(format!("--gpu takes auto, true or false, got '{}'", a.gpu))
    })?;
    let leaf = a.leaf_size.unwrap_or_else(|| {
        if gpu_expected(gpu) && !a.direct {
            kind.default_leaf_size(order) * GPU_LEAF_FACTOR
        } else {
            // Targets that are the sources: on one rank the near field's mutual pairs; the
            // same leaves on every rank count, so that K ranks give one rank's values.
            kind.default_leaf_size_for(order, a.targets.is_none())
        }
    });
    if leaf == 0 {
        return Err(CliError::Arg("--leaf-size must be positive".into()));
    }
    Ok((kind, order, leaf, gpu))
}

/// This rank's inputs.
struct Inputs {
    n_sources: usize,
    n_targets: usize,
    sources: Vec<[f64; 3]>,
    density: Vec<f64>,
    normals: Option<Vec<[f64; 3]>>,
    targets: Vec<[f64; 3]>,
}

fn read_inputs(a: &FmmArgs, kind: FmmKernel, comm: &dyn Communicator) -> Result<Inputs, String> {
    let kernel = kind.near();
    let (n, sources) = read_share(&a.sources, 3, None, comm)?;
    let (_, density) = read_share(&a.density, kernel.density_dim(), Some(n), comm)?;
    let normals = match (&a.normals, kernel.needs_normals()) {
        (Some(p), true) => Some(points(read_share(p, 3, Some(n), comm)?.1)),
        (None, true) => return Err(format!("--kernel {} needs --normals", kernel.name())),
        (Some(_), false) => return Err(format!("--kernel {} takes no --normals", kernel.name())),
        (None, false) => None,
    };
    let (m, targets) = match &a.targets {
        Some(p) => read_share(p, 3, None, comm)?,
        None => (n, sources.clone()),
    };
    Ok(Inputs {
        n_sources: n,
        n_targets: m,
        sources: points(sources),
        density,
        normals,
        targets: points(targets),
    })
}

/// Run `mobo fmm`.
pub fn fmm(a: FmmArgs) -> Result<(), CliError> {
    if a.no_cache {
        mobo::fmm::fit_cache::disable();
    }
    let comm = world();
    let result = fmm_on(comm.as_ref(), &a);
    match result {
        Err(e) if comm.rank() != 0 && every_rank_has(&e) => Err(CliError::ReportedElsewhere),
        r => r,
    }
}

/// Errors that every rank returns alike: bad arguments (the same on every rank) and failures
/// agreed across ranks (a rank's bad input, reported to all as `CommError::Remote`). Rank 0
/// reports these; the other ranks exit with status 0, so that `mpirun` does not abort the
/// job before rank 0 has printed the message and set the job's non-zero status.
fn every_rank_has(e: &CliError) -> bool {
    matches!(
        e,
        CliError::Arg(_)
            | CliError::Comm(CommError::Remote { .. })
            | CliError::Fmm(FmmError::Comm(CommError::Remote { .. }))
    )
}

fn fmm_on(comm: &dyn Communicator, a: &FmmArgs) -> Result<(), CliError> {
    let (kind, order, leaf, gpu) = settings(a)?;
    let gpu_precision = match a.gpu_precision.as_deref() {
        None => None,
        Some("f32") => Some(GpuPrecision::F32),
        Some("f64") => Some(GpuPrecision::F64),
        Some(o) => {
            return Err(CliError::Arg(format!(
                "--gpu-precision takes f32 or f64, got '{o}'"
            )))
        }
    };
    if a.repeat == 0 {
        return Err(CliError::Arg("--repeat must be at least 1".into()));
    }
    if a.direct && gpu == GpuChoice::On {
        return Err(CliError::Arg(
            "--direct runs on the CPU; --gpu applies to the FMM's near field".into(),
        ));
    }
    let k = comm.size();
    if a.direct && k > 1 {
        return Err(CliError::Arg(format!(
            "--direct runs on one rank (started on {k}); run it without mpirun"
        )));
    }
    let inputs = read_inputs(a, kind, comm);
    let inputs = match comm.size() {
        1 => inputs.map_err(CliError::Arg)?,
        _ => {
            let agreed = comm.agree(inputs.as_ref().map(|_| ()).map_err(Clone::clone));
            agreed.map_err(mobo::fmm::FmmError::from)?;
            inputs.map_err(CliError::Arg)?
        }
    };
    let kernel = kind.near();
    let od = kernel.output_dim();
    let mut u = vec![0.0; inputs.targets.len() * od];
    let t0 = Instant::now();
    let mut fmm = Fmm::new_on(
        comm,
        kind,
        &inputs.sources,
        inputs.normals.as_deref(),
        &inputs.targets,
        order,
        leaf,
    )?;
    fmm.set_m2l_buffer_bytes(
        usize::try_from(a.m2l_buffer_mib.saturating_mul(1 << 20)).unwrap_or(usize::MAX),
    );
    let near = if a.direct {
        None
    } else {
        Some(choose(&mut fmm, gpu, gpu_precision, Some(a.digits))?)
    };
    let setup = t0.elapsed().as_secs_f64();
    let mut evals_s = Vec::with_capacity(a.repeat);
    for _ in 0..a.repeat.max(1) {
        u.fill(0.0);
        let t1 = Instant::now();
        if a.direct {
            fmm.direct(&inputs.density, &mut u)?;
        } else {
            fmm.evaluate_on(comm, &inputs.density, &mut u)?;
        }
        evals_s.push(t1.elapsed().as_secs_f64());
    }
    let eval = evals_s.iter().copied().fold(f64::INFINITY, f64::min);
    let eval_first = evals_s[0];
    // Gather the values (rows in rank order are the file's order) and per-rank statistics.
    let parts = comm.gather_f64(&u, 0)?;
    let t = fmm.timings;
    let mut stats = vec![
        fmm.tree.n_owned_sources as f64,
        fmm.tree.targets.len() as f64,
        eval,
        fmm.comm.bytes_sent as f64,
        fmm.comm.seconds,
        setup,
    ];
    // Columns 6..15: the phases.
    stats.extend(t.phases().map(|(_, seconds)| seconds));
    stats.extend([
        fmm.comm.let_bytes_sent as f64,
        fmm.comm.top_bytes_received as f64,
        fmm.tree.roots[fmm.tree.rank].len() as f64,
        {
            let (repeated, all) = fmm.tree.repeated_far_work();
            repeated as f64 / all.max(1) as f64
        },
        fmm.setup_bytes_sent as f64,
        fmm.comm.messages_sent as f64,
        fmm.tree
            .top_reduce
            .iter()
            .chain(&fmm.tree.top_broadcast)
            .map(|s| s.inn.len())
            .sum::<usize>() as f64,
    ]);
    let all = comm.gather_f64(&stats, 0)?;
    if comm.rank() != 0 {
        return Ok(());
    }
    let values: Vec<f64> = parts.concat();
    let shape: Vec<usize> = if od == 1 {
        vec![inputs.n_targets]
    } else {
        vec![inputs.n_targets, od]
    };
    mobo::io::npy::write_f64(&a.out, &shape, &values)?;
    let col = |i: usize| -> Vec<f64> { all.iter().map(|s| s[i]).collect() };
    let max = |i: usize| col(i).into_iter().fold(0.0, f64::max);
    let evals = col(2);
    let mean_eval = evals.iter().sum::<f64>() / k as f64;
    let names = t.phases().map(|(name, _)| name);
    let phases_max: serde_json::Map<String, serde_json::Value> = names
        .iter()
        .enumerate()
        .map(|(i, n)| (n.to_string(), max(6 + i).into()))
        .collect();
    let as_int = |v: Vec<f64>| -> Vec<u64> { v.into_iter().map(|x| x as u64).collect() };
    let line = serde_json::json!({
        "kernel": kernel.name(),
        "n_sources": inputs.n_sources,
        "n_targets": inputs.n_targets,
        "digits": a.digits,
        "order": order,
        "method": if a.direct { "direct" } else { "fmm" },
        "leaf_size": leaf,
        "tree_depth": fmm.tree.depth(),
        "boxes": fmm.tree.boxes.len(),
        "threads": rayon::current_num_threads(),
        "setup_s": max(5),
        "m2l_buffer_peak_mib": fmm.m2l_peak_bytes() as f64 / (1u64 << 20) as f64,
        "operator_cache": mobo::fmm::fit_cache::dir().map(|d| d.display().to_string()),
        "eval_s": max(2),
        "eval_first_s": eval_first,
        "repeat": a.repeat,
        "near_field": near,
        "phases_s": if a.direct { serde_json::Value::Null } else { serde_json::to_value(fmm.timings).unwrap_or_default() },
        "ranks": k,
        "rank_sources": as_int(col(0)),
        "rank_targets": as_int(col(1)),
        "rank_eval_s": evals,
        "load_imbalance": if mean_eval > 0.0 { max(2) / mean_eval } else { 1.0 },
        "rank_bytes_sent": as_int(col(3)),
        "rank_let_bytes_sent": as_int(col(15)),
        "rank_top_bytes_received": as_int(col(16)),
        "rank_local_roots": as_int(col(17)),
        "rank_repeated_far_fraction": col(18),
        "rank_setup_bytes_sent": as_int(col(19)),
        "rank_messages_sent": as_int(col(20)),
        "rank_top_messages_received": as_int(col(21)),
        "top_stages": [fmm.tree.top_reduce.len(), fmm.tree.top_broadcast.len()],
        "rank_comm_s": col(4),
        "phases_max_s": phases_max,
    });
    println!("{line}");
    Ok(())
}
