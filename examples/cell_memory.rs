//! Bytes per cell of a suspension's per-cell state at order `p` (quadrature `2p`): builds `N`
//! steppers of RBCs, steps each once in shear, and reports the growth of the resident set
//! (`/proc/self/statm`) per cell after construction and after the first step (when the dense
//! operators, the preconditioner and the reparametrisation plans exist).
//!
//! `cargo run --release --example cell_memory -- [P] [N] [MODE]`, MODE = dense | compact.
use mobo::timestep::semi_implicit::{VesicleParams, VesicleStepper};
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
        },
        correct_drift: true,
        reparametrize: Some(ReparamParams::default()),
        preconditioner: true,
        scheme: mobo::timestep::semi_implicit::TimeScheme::Bdf2,
        viscosity_ratio: 1.0,
    };
    let rbc = shapes::rbc(p).unwrap();
    // One stepper first: the tables shared per (p, q) are built once per process.
    let mut first = VesicleStepper::new(p, params).unwrap();
    let mut c = rbc.coefs().to_vec();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    first.step(&mut c, &shear).unwrap();
    let r0 = rss_bytes();
    let mut st: Vec<VesicleStepper> = (0..n)
        .map(|_| VesicleStepper::new(p, params).unwrap())
        .collect();
    let r1 = rss_bytes();
    let mut coefs: Vec<Vec<f64>> = (0..n).map(|_| rbc.coefs().to_vec()).collect();
    for (s, c) in st.iter_mut().zip(coefs.iter_mut()) {
        s.step(c, &shear).unwrap();
    }
    let r2 = rss_bytes();
    println!(
        "own state of a cell (VesicleStepper::memory_bytes): {:.2} MB",
        st[0].memory_bytes() as f64 / 1e6
    );
    println!(
        "p = {p}, {n} cells: {:.2} MB per cell after construction, {:.2} MB per cell after one step (shared tables: {:.1} MB)",
        (r1 - r0) / n as f64 / 1e6,
        (r2 - r0) / n as f64 / 1e6,
        r0 / 1e6
    );
}
