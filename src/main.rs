//! The `mobo` command-line program.

use std::process::ExitCode;
use std::time::Instant;

use clap::{Parser, Subcommand};
use mobo::sph_harmonics::{Deriv, ShTransform};

mod cli_error;
mod fmm_command;
use cli_error::CliError;
use fmm_command::FmmArgs;

#[derive(Parser)]
#[command(
    name = "mobo",
    version,
    about = "Deformable cells in Stokes flow: spherical-harmonic surfaces, boundary integrals, FMM",
    long_about = "Deformable cells in Stokes flow: spherical-harmonic surfaces, boundary integrals and a \
kernel-independent FMM.\n\nWith no subcommand, runs the built-in demo scene (mobo run: one red blood cell in shear)."
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// The built-in demo: a red blood cell as a spherical-harmonic surface (transforms,
    /// derivatives, area, volume, reduced volume) and batched transform speed.
    Demo {
        /// Spherical-harmonic order.
        #[arg(long, default_value_t = 16)]
        order: usize,
    },
    /// Brownian dynamics with hydrodynamic interactions from a scene file with a [brownian]
    /// section; writes trajectory.npy, observables.csv and summary.json.
    Brownian {
        /// The scene file (TOML).
        scene: std::path::PathBuf,
        /// Output directory (default: out/<scene name>).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Dissipative particle dynamics from a scene file with a [dpd] section (periodic box,
    /// optional periodic Poiseuille flow whose profile gives the viscosity). Writes
    /// summary.json, observables.csv, profile.csv, scene.toml and checkpoint.bin; Ctrl-C stops
    /// after the current step with a checkpoint; `mobo dpd --resume DIR` continues bit-for-bit.
    Dpd {
        /// The scene file (TOML).
        #[arg(required_unless_present = "resume")]
        scene: Option<std::path::PathBuf>,
        /// Output directory (default: out/<scene name>).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Continue the run in DIR from its checkpoint (its scene.toml is the scene).
        #[arg(long, value_name = "DIR", conflicts_with_all = ["scene", "out"])]
        resume: Option<std::path::PathBuf>,
        /// Stop after this many steps (with a checkpoint); continue later with --resume.
        #[arg(long)]
        max_steps: Option<u64>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Evaluate an N-body sum on user data (.npy float64 files) with the kernel-independent
    /// FMM (or --direct); prints one JSON line with the settings and timings.
    Fmm(FmmArgs),
    /// Run a cell scene (TOML); without a scene, the built-in demo (one red blood cell in shear).
    /// Writes summary.json, frames (frames/*.npy, vtk/*.vtp, frames.h5 as the scene's [output]
    /// asks), scene.toml and checkpoint.bin into the output directory. Ctrl-C stops after the
    /// current step with a checkpoint; `mobo run --resume DIR` continues bit-for-bit.
    Run {
        /// The scene file (TOML); omitted: the built-in demo scene.
        scene: Option<std::path::PathBuf>,
        /// Output directory (default: out/<scene name>, out/demo for the demo).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Continue the run in DIR from its checkpoint (its scene.toml is the scene).
        #[arg(long, value_name = "DIR", conflicts_with_all = ["scene", "out"])]
        resume: Option<std::path::PathBuf>,
        /// Stop after this many steps (with a checkpoint); continue later with --resume.
        #[arg(long)]
        max_steps: Option<usize>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Reports on the solver: `mobo report accuracy` (error against time per step, per knob).
    Report {
        #[command(subcommand)]
        what: ReportCommand,
    },
    /// Time batched forward + inverse transforms; prints one JSON line.
    BenchSht {
        /// Spherical-harmonic order p.
        #[arg(long, default_value_t = 16)]
        order: usize,
        /// Number of surfaces (3 components each).
        #[arg(long, default_value_t = 1000)]
        surfaces: usize,
        /// Threads (1 = the serial path).
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// Repetitions (best time is reported).
        #[arg(long, default_value_t = 5)]
        reps: usize,
    },
}

#[derive(Subcommand)]
enum ReportCommand {
    /// Accuracy against wall time per step: each knob (order, upsampling, FMM digits, GMRES
    /// tolerance, dt, scheme) varied with the others at a high-accuracy reference. Writes
    /// accuracy.csv, accuracy.md and accuracy.png into the output directory.
    Accuracy {
        /// The scene (TOML); omitted: the built-in study scene (two red blood cells in shear).
        #[arg(long)]
        scene: Option<std::path::PathBuf>,
        /// Output directory.
        #[arg(long, default_value = "out/report")]
        out: std::path::PathBuf,
        /// Wall-time budget of the whole study in minutes.
        #[arg(long, default_value_t = 10.0)]
        budget_minutes: f64,
        /// Time at which the runs are compared (the scene's t_end is not used).
        #[arg(long, default_value_t = 1.0)]
        t_end: f64,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command.unwrap_or(Command::Run {
        scene: None,
        out: None,
        resume: None,
        max_steps: None,
        quiet: false,
    }) {
        Command::Demo { order } => demo(order),
        Command::Brownian { scene, out, quiet } => brownian(&scene, out, quiet),
        Command::Fmm(args) => fmm_command::fmm(args),
        Command::Dpd {
            scene,
            out,
            resume,
            max_steps,
            quiet,
        } => dpd(scene, out, resume, max_steps, quiet),
        Command::Run {
            scene,
            out,
            resume,
            max_steps,
            quiet,
        } => run(scene, out, resume, max_steps, quiet),
        Command::Report {
            what:
                ReportCommand::Accuracy {
                    scene,
                    out,
                    budget_minutes,
                    t_end,
                },
        } => report_accuracy(scene, &out, budget_minutes, t_end),
        Command::BenchSht {
            order,
            surfaces,
            threads,
            reps,
        } => bench_sht(order, surfaces, threads, reps),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Interrupted) => ExitCode::from(130),
        Err(CliError::ReportedElsewhere) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mobo: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Grid values of the biconcave RBC (unit equivalent radius), components x, y, z.
fn rbc_grid(sht: &ShTransform) -> Vec<f64> {
    let alpha = 1.385_818_9;
    let g = sht.grid();
    let np = g.n_points();
    let mut out = vec![0.0; 3 * np];
    for j in 0..np {
        let (t, f) = g.angles(j);
        let (s, c) = t.sin_cos();
        out[j] = alpha * s * f.cos();
        out[np + j] = alpha * s * f.sin();
        out[2 * np + j] = 0.5 * alpha * (0.207 + 2.003 * s * s - 1.123 * s.powi(4)) * c;
    }
    out
}

fn demo(order: usize) -> Result<(), CliError> {
    if order < 2 {
        return Err(CliError::Arg(format!(
            "--order must be at least 2, got {order}"
        )));
    }
    println!(
        "mobo {} — demo: a red blood cell on a spherical-harmonic grid",
        env!("CARGO_PKG_VERSION")
    );
    let t0 = Instant::now();
    let sht = ShTransform::new(order)?;
    let np = sht.n_points();
    let nc = sht.n_coefs();
    let mut ws = sht.workspace();
    let x = rbc_grid(&sht);
    let mut coefs = vec![0.0; 3 * nc];
    sht.forward(&x, &mut coefs, &mut ws)?;
    // Surface derivatives from the expansion.
    let mut xt = vec![0.0; 3 * np];
    let mut xp = vec![0.0; 3 * np];
    let mut xv = vec![0.0; 3 * np];
    sht.synthesize(
        &coefs,
        &[Deriv::Value, Deriv::Theta, Deriv::Phi],
        &mut [&mut xv, &mut xt, &mut xp],
        &mut ws,
    )?;
    let roundtrip = mobo::check::rel_max_error(&xv, &x);
    let g = sht.grid();
    let w = g.quadrature_weights();
    let (mut area, mut vol) = (0.0, 0.0);
    for j in 0..np {
        let a = [xt[j], xt[np + j], xt[2 * np + j]];
        let b = [xp[j], xp[np + j], xp[2 * np + j]];
        let n = [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ];
        let s = g.sin_theta[j / (2 * order)];
        let jac = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() / s;
        area += w[j] * jac;
        vol += w[j] * (xv[j] * n[0] + xv[np + j] * n[1] + xv[2 * np + j] * n[2]) / (3.0 * s);
    }
    let reduced = 6.0 * std::f64::consts::PI.sqrt() * vol / area.powf(1.5);
    // Spectral content per degree.
    let degrees = sht.layout().degrees();
    let mut energy = vec![0.0; order + 1];
    for c in coefs.chunks_exact(nc) {
        for (a, &n) in c.iter().zip(&degrees) {
            energy[n] += a * a;
        }
    }
    println!("  order p = {order}: {np} grid points, {nc} coefficients per component");
    println!("  round trip (grid -> coefficients -> grid): relative error {roundtrip:.2e}");
    println!(
        "  area {area:.10}, volume {vol:.10}, reduced volume {reduced:.6} (design value ~0.644)"
    );
    let last_nonzero = energy
        .iter()
        .rposition(|&e| e > 1e-26 * energy[1])
        .unwrap_or(0);
    println!("  highest degree with energy above 1e-26: {last_nonzero} (the shape is band-limited at degree 5)");
    // Batched transforms: 1000 cells × 3 components.
    let cells = 1000;
    let big: Vec<f64> = x.iter().cycle().take(cells * 3 * np).copied().collect();
    let mut big_c = vec![0.0; cells * 3 * nc];
    let mut back = vec![0.0; big.len()];
    sht.forward(&big, &mut big_c, &mut ws)?; // warm-up
    let t = Instant::now();
    sht.forward(&big, &mut big_c, &mut ws)?;
    sht.inverse(&big_c, &mut back, &mut ws)?;
    let dt = t.elapsed().as_secs_f64();
    println!(
        "  {cells} cells x 3 components, forward + inverse on 1 thread: {:.1} ms ({:.2} GFLOP/s in the Legendre GEMMs over the whole time)",
        dt * 1e3,
        2.0 * sht.legendre_flops(3 * cells) / dt / 1e9
    );
    println!("done in {:.2} s", t0.elapsed().as_secs_f64());
    Ok(())
}

/// `mobo report accuracy`.
fn report_accuracy(
    scene: Option<std::path::PathBuf>,
    out: &std::path::Path,
    budget_minutes: f64,
    t_end: f64,
) -> Result<(), CliError> {
    use mobo::report::accuracy;
    if !(budget_minutes.is_finite() && budget_minutes > 0.0) {
        return Err(CliError::Arg(format!(
            "--budget-minutes must be a positive number, got {budget_minutes}"
        )));
    }
    if !(t_end.is_finite() && t_end > 0.0) {
        return Err(CliError::Arg(format!(
            "--t-end must be a positive number, got {t_end}"
        )));
    }
    let (sc, name) = match &scene {
        Some(path) => (mobo::scene::cells::load(path)?, path.display().to_string()),
        None => (
            accuracy::study_scene()?,
            "built-in study scene (two RBCs in shear)".to_string(),
        ),
    };
    // Fail on a missing font before spending the budget.
    mobo::report::plot::ensure_font()?;
    let opts = accuracy::StudyOptions {
        budget_s: budget_minutes * 60.0,
        t_end,
        progress: true,
        ..Default::default()
    };
    let study = accuracy::run_study(&sc, &name, &opts)?;
    let files = accuracy::write_report(&study, out)?;
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}

fn bench_sht(order: usize, surfaces: usize, threads: usize, reps: usize) -> Result<(), CliError> {
    if surfaces == 0 || threads == 0 || reps == 0 {
        return Err(CliError::Arg(
            "--surfaces, --threads and --reps must be positive".into(),
        ));
    }
    let sht = ShTransform::new(order)?;
    let nf = 3 * surfaces;
    let mut grid: Vec<f64> = (0..nf * sht.n_points())
        .map(|i| ((i % 97) as f64).sin())
        .collect();
    let mut coefs = vec![0.0; nf * sht.n_coefs()];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| CliError::Arg(format!("cannot start {threads} threads: {e}")))?;
    let (mut best_f, mut best_i) = (f64::INFINITY, f64::INFINITY);
    let mut ws = sht.workspace();
    for _ in 0..=reps {
        let t = Instant::now();
        if threads == 1 {
            sht.forward(&grid, &mut coefs, &mut ws)?;
        } else {
            pool.install(|| sht.forward_par(&grid, &mut coefs))?;
        }
        best_f = best_f.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        if threads == 1 {
            sht.inverse(&coefs, &mut grid, &mut ws)?;
        } else {
            pool.install(|| sht.inverse_par(&coefs, &mut grid))?;
        }
        best_i = best_i.min(t.elapsed().as_secs_f64());
    }
    let flops = 2.0 * sht.legendre_flops(nf);
    println!(
        "{{\"p\":{order},\"surfaces\":{surfaces},\"functions\":{nf},\"threads\":{threads},\"forward_s\":{best_f:.6e},\"inverse_s\":{best_i:.6e},\"legendre_gflops\":{:.3}}}",
        flops / (best_f + best_i) / 1e9
    );
    Ok(())
}

fn run(
    scene: Option<std::path::PathBuf>,
    out: Option<std::path::PathBuf>,
    resume: Option<std::path::PathBuf>,
    max_steps: Option<usize>,
    quiet: bool,
) -> Result<(), CliError> {
    use mobo::run::cells as cells_run;
    use mobo::scene::{cells, read_scene_file};
    let scene = scene.or_else(|| resume.as_ref().map(|d| d.join(cells_run::SCENE_COPY)));
    let (sc, text, name) = match &scene {
        Some(path) => {
            let text = read_scene_file(path)?;
            (
                cells::parse(path, &text)?,
                text,
                path.file_stem().unwrap_or_default().to_os_string(),
            )
        }
        None => (
            cells::parse(
                std::path::Path::new("<built-in demo>"),
                cells_run::DEMO_SCENE,
            )?,
            cells_run::DEMO_SCENE.to_string(),
            "demo".into(),
        ),
    };
    let out = resume
        .clone()
        .or(out)
        .unwrap_or_else(|| std::path::Path::new("out").join(name));
    let comm = fmm_command::world();
    let root = comm.rank() == 0;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    watch_stop_signals(stop.clone(), root);
    let options = cells_run::RunOptions {
        quiet: quiet || !root,
        resume: resume.is_some(),
        max_steps,
        stop: Some(stop.clone()),
    };
    if !quiet && root {
        eprintln!(
            "mobo run: {} ({} cells, p = {}, dt = {}, t_end = {}{}) -> {}",
            scene
                .as_ref()
                .map_or("built-in demo".into(), |p| p.display().to_string()),
            sc.cells.len(),
            sc.numerics.order,
            sc.numerics.dt,
            sc.numerics.t_end,
            ranks_note(comm.size()),
            out.display()
        );
        for e in &sc.effects {
            eprintln!(
                "  {} {}: {}",
                if e.enabled { "+" } else { "-" },
                e.name,
                e.reason
            );
        }
    }
    let s = match cells_run::run_on(comm.as_ref(), &sc, &text, &out, &options) {
        Ok(Some(s)) => s,
        // Rank 0 reports (every failure is returned on every rank).
        Ok(None) => return Ok(()),
        Err(_) if !root => return Err(CliError::ReportedElsewhere),
        Err(e) => return Err(e.into()),
    };
    if !s.completed {
        println!(
            "stopped at step {} (t = {}): checkpoint in {}; continue with `mobo run --resume {}`",
            s.steps,
            s.final_time,
            out.display(),
            out.display()
        );
        // Stopped early without a step limit: interrupted (here or on another rank).
        return if stop.load(std::sync::atomic::Ordering::Relaxed) || max_steps.is_none() {
            Err(CliError::Interrupted)
        } else {
            Ok(())
        };
    }
    // A capsule's area changes with its strain: not a drift.
    let area_label = if sc.cells.iter().any(|c| !c.inextensible) {
        "area change"
    } else {
        "area drift"
    };
    println!(
        "{} steps to t = {} in {:.2} s ({:.1} cell-steps/s); GMRES {:.1} iterations per step (max {}); {area_label} {:.1e}, volume drift {:.1e}; inclination {:.2}°; results in {}",
        s.steps,
        s.final_time,
        s.wall_s,
        s.cell_steps_per_core_second,
        s.gmres_iterations_mean,
        s.gmres_iterations_max,
        s.area_drift,
        s.volume_drift,
        s.inclination_deg,
        out.display()
    );
    for pk in &s.packings {
        println!(
            "packed: [[cells]] #{} as {} cells at {:.1} % of the {} in {:.1} s (smallest gap {})",
            pk.entry + 1,
            pk.cells,
            100.0 * pk.volume_fraction,
            match pk.region {
                "walls" => "walls' fluid",
                "tube window" => "recycled tube's window",
                _ => "cube",
            },
            pk.seconds,
            pk.smallest_gap
                .map_or("beyond the projection's range".to_string(), |g| format!(
                    "{g:.4}"
                ))
        );
    }
    if let Some(st) = s.counters.start_up {
        println!(
            "start-up: {} pass{} before the first step (the coupled cells' tension and membrane velocity at t = 0; last change {:.1e} of the tension)",
            st.passes,
            if st.passes == 1 { "" } else { "es" },
            st.tension_change
        );
    }
    Ok(())
}

/// ", K ranks" for a banner line under MPI, nothing on one rank.
fn ranks_note(ranks: usize) -> String {
    match ranks {
        1 => String::new(),
        k => format!(", {k} ranks"),
    }
}

/// Set by SIGUSR1 (async-signal-safe: one atomic store).
static USR1: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

extern "C" fn on_usr1(_: libc::c_int) {
    USR1.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// Stop a run after the current step (every rank agrees at the end of each step, then a
/// checkpoint is written) on Ctrl-C, SIGTERM or SIGUSR1. `mpirun` forwards SIGUSR1 to every
/// rank; on Ctrl-C (OpenMPI 4.1, measured) it sends SIGCONT, then SIGTERM after
/// `OMPI_MCA_odls_base_sigkill_timeout` seconds and SIGKILL as many seconds later, which is the
/// time a rank has to finish its step and the checkpoint. Signals within
/// 3 s of the first count as one; a later one ends the process at once (exit status 130).
fn watch_stop_signals(stop: std::sync::Arc<std::sync::atomic::AtomicBool>, root: bool) {
    use std::sync::atomic::Ordering;
    let first = std::sync::Mutex::new(None::<std::time::Instant>);
    let flag = stop.clone();
    let _ = ctrlc::set_handler(move || {
        let mut f = first.lock().unwrap_or_else(|e| e.into_inner());
        match *f {
            Some(t) if t.elapsed().as_secs_f64() > 3.0 => std::process::exit(130),
            Some(_) => {}
            None => {
                *f = Some(std::time::Instant::now());
                flag.store(true, Ordering::Relaxed);
                if root {
                    eprintln!(
                        "\nmobo run: stopping after this step (checkpoint follows); Ctrl-C again to abort"
                    );
                }
            }
        }
    });
    // SAFETY: installs a handler that only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGUSR1, on_usr1 as *const () as libc::sighandler_t);
    }
    std::thread::spawn(move || loop {
        if USR1.load(Ordering::Relaxed) {
            stop.store(true, Ordering::Relaxed);
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    });
}

fn brownian(
    scene: &std::path::Path,
    out: Option<std::path::PathBuf>,
    quiet: bool,
) -> Result<(), CliError> {
    // Every rank reads the scene and runs every step (its rows of the O(N²) pass); any error
    // is every rank's, so rank 0 alone reports it.
    let comm = fmm_command::world();
    let root = comm.rank() == 0;
    let result = brownian_on(comm.as_ref(), scene, out, quiet || !root);
    match result {
        Err(_) if !root => Err(CliError::ReportedElsewhere),
        r => r,
    }
}

fn brownian_on(
    comm: &dyn mobo::comm::Communicator,
    scene: &std::path::Path,
    out: Option<std::path::PathBuf>,
    quiet: bool,
) -> Result<(), CliError> {
    let sc = mobo::scene::brownian::load(scene)?;
    let out = out
        .unwrap_or_else(|| std::path::Path::new("out").join(scene.file_stem().unwrap_or_default()));
    if !quiet {
        eprintln!(
            "mobo brownian: {} ({} beads, {} steps, noise {:?}{}) -> {}",
            scene.display(),
            sc.positions.len(),
            sc.steps,
            sc.params.noise,
            ranks_note(comm.size()),
            out.display()
        );
        for e in mobo::run::brownian::effects(&sc) {
            eprintln!(
                "  {} {}: {}",
                if e.enabled { "+" } else { "-" },
                e.name,
                e.reason
            );
        }
    }
    let s = mobo::run::brownian::run_on(comm, &sc, &out, !quiet)?;
    if comm.rank() == 0 {
        println!(
            "{} beads, {} steps in {:.2} s ({:.0} steps/s); D_CM estimate {:.4} (D0 = {:.4}); <Rg^2> = {:.4}; <Ree^2> = {:.4}",
            s.beads, s.steps, s.wall_s, s.steps_per_second, s.com_diffusion_estimate, s.d0, s.mean_rg2, s.mean_end_to_end_sq
        );
    }
    Ok(())
}

fn dpd(
    scene: Option<std::path::PathBuf>,
    out: Option<std::path::PathBuf>,
    resume: Option<std::path::PathBuf>,
    max_steps: Option<u64>,
    quiet: bool,
) -> Result<(), CliError> {
    use mobo::run::dpd as dpd_run;
    use mobo::scene::{dpd, read_scene_file};
    let path = match (&scene, &resume) {
        (Some(p), _) => p.clone(),
        (None, Some(d)) => d.join(dpd_run::SCENE_COPY),
        (None, None) => {
            return Err(CliError::Arg(
                "a scene file or --resume DIR is required".into(),
            ))
        }
    };
    let text = read_scene_file(&path)?;
    let sc = dpd::parse(&path, &text)?;
    let out = resume
        .clone()
        .or(out)
        .unwrap_or_else(|| std::path::Path::new("out").join(path.file_stem().unwrap_or_default()));
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    watch_stop_signals(stop.clone(), true);
    if !quiet {
        let l = sc.params.box_len;
        eprintln!(
            "mobo dpd: {} (box {}×{}×{}, density {}, {} steps of dt = {}) -> {}",
            path.display(),
            l[0],
            l[1],
            l[2],
            sc.density,
            sc.steps,
            sc.params.dt,
            out.display()
        );
        for e in dpd_run::effects(&sc) {
            eprintln!(
                "  {} {}: {}",
                if e.enabled { "+" } else { "-" },
                e.name,
                e.reason
            );
        }
    }
    let opts = dpd_run::DpdRunOptions {
        quiet,
        resume: resume.is_some(),
        max_steps,
        stop: Some(stop.clone()),
    };
    let s = dpd_run::run(&sc, &text, &out, &opts)?;
    if !s.completed {
        println!(
            "stopped at step {} (t = {}): checkpoint in {}; continue with `mobo dpd --resume {}`",
            s.steps,
            s.final_time,
            out.display(),
            out.display()
        );
        return if stop.load(std::sync::atomic::Ordering::Relaxed) {
            Err(CliError::Interrupted)
        } else {
            Ok(())
        };
    }
    let visc = s
        .viscosity
        .as_ref()
        .map(|v| {
            format!(
                "; viscosity {:.4} ± {:.4} (kinetic theory {:.4})",
                v.value, v.stderr, v.kinetic_theory.total
            )
        })
        .unwrap_or_default();
    let kbt = match s.thermal_temperature {
        Some(t) => format!(
            "k_BT {t:.4} about the mean flow ({:.4} with it)",
            s.temperature
        ),
        None => format!("k_BT {:.4}", s.temperature),
    };
    println!(
        "{} particles, {} steps to t = {} in {:.2} s ({:.3e} particle-steps/s, {:.2} ms/step); {kbt}, pressure {:.3}{visc}; results in {}",
        s.particles,
        s.steps,
        s.final_time,
        s.wall_s,
        s.particle_steps_per_second,
        s.ms_per_step,
        s.pressure,
        out.display()
    );
    Ok(())
}
