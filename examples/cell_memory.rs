//! Bytes per cell of a suspension's per-cell state at order `p` (quadrature `2p`): builds `N`
//! steppers of RBCs, steps each twice in shear (BDF2), and reports the growth of the resident
//! set (`/proc/self/statm`) per cell after construction and after the two steps (when the
//! dense operators and both preconditioners exist).
//!
//! `cargo run --release --example cell_memory -- [P] [N] [STORAGE]`, STORAGE = coefficients
//! (default) | grid | matrix_free; also prints the time of a third step per cell (one thread).
use mobo::timestep::semi_implicit::{OperatorStorage, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes;

fn rss_bytes() -> f64 {
    let s = std::fs::read_to_string("/proc/self/statm").unwrap();
    let pages: f64 = s.split_whitespace().nth(1).unwrap().parse().unwrap();
    pages * 4096.0
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let p: usize = a.get(1).map_or(12, |s| s.parse().unwrap());
    let n: usize = a.get(2).map_or(20, |s| s.parse().unwrap());
    let storage = match a.get(3).map_or("coefficients", |s| s.as_str()) {
        "coefficients" => OperatorStorage::Coefficients,
        "grid" => OperatorStorage::Grid,
        "matrix_free" => OperatorStorage::MatrixFree,
        other => panic!("unknown storage {other}"),
    };
    let params = VesicleParams {
        bending_modulus: 0.1,
        viscosity: 1.0,
        force: [0.0; 3],
        dt: 0.05,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: 1e-8,
            restart: 30,
            max_iters: 300,
            ..Default::default()
        },
        correct_drift: true,
        reparametrize: Some(ReparamParams::default()),
        preconditioner: true,
        scheme: mobo::timestep::semi_implicit::TimeScheme::Bdf2,
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    };
    let rbc = shapes::rbc(p).unwrap();
    // One stepper first: the tables shared per (p, q) are built once per process.
    let mut first = VesicleStepper::new(p, params).unwrap();
    let mut c = rbc.coefs().to_vec();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    first.step(&mut c, &shear).unwrap();
    let r0 = rss_bytes();
    let mut st: Vec<VesicleStepper> = (0..n)
        .map(|_| {
            let mut s = VesicleStepper::new(p, params).unwrap();
            s.set_operator_storage(storage);
            s
        })
        .collect();
    let r1 = rss_bytes();
    let mut coefs: Vec<Vec<f64>> = (0..n).map(|_| rbc.coefs().to_vec()).collect();
    // Two steps: the first is Euler, the second BDF2 (its own preconditioner).
    for _ in 0..2 {
        for (s, c) in st.iter_mut().zip(coefs.iter_mut()) {
            s.step(c, &shear).unwrap();
        }
    }
    let r2 = rss_bytes();
    let t0 = std::time::Instant::now();
    let mut iters = 0;
    for (s, c) in st.iter_mut().zip(coefs.iter_mut()) {
        iters += s.step(c, &shear).unwrap().gmres.iterations;
    }
    println!(
        "{storage:?}: third step {:.3} s per cell, {:.1} GMRES iterations per cell",
        t0.elapsed().as_secs_f64() / n as f64,
        iters as f64 / n as f64
    );
    println!(
        "own state of a cell (VesicleStepper::memory_bytes): {:.2} MB",
        st[0].memory_bytes() as f64 / 1e6
    );
    println!(
        "p = {p}, {n} cells: {:.2} MB per cell after construction, {:.2} MB per cell after two steps (shared tables: {:.1} MB)",
        (r1 - r0) / n as f64 / 1e6,
        (r2 - r0) / n as f64 / 1e6,
        r0 / 1e6
    );
}
