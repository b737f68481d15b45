//! Times the parts of the FMM setup (fits, M2M/L2L matrices, M2L spectra) for one kernel and
//! order: `cargo run --release --example fmm_setup_probe -- stokeslet 15`.
use mobo::fmm::kernels::{Laplace, Stokeslet};
use mobo::fmm::m2l_fft::FftM2l;
use mobo::fmm::operators::Translations;
use mobo::fmm::surface::CubeSurface;
use mobo::fmm::{fit_cache, Kernel};
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let kernel: Box<dyn Kernel> = match a.get(1).map(String::as_str) {
        Some("laplace") => Box::new(Laplace),
        _ => Box::new(Stokeslet),
    };
    let p: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(15);
    let dir = fit_cache::dir();
    let t = Instant::now();
    let tr = Translations::new(kernel.as_ref(), p, 1e-10, dir.as_deref()).unwrap();
    println!(
        "translations (fits from cache: {}) {:.3} s",
        dir.is_some(),
        t.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    let m2l = FftM2l::new(kernel.as_ref(), &CubeSurface::new(p));
    println!("m2l spectra {:.3} s", t.elapsed().as_secs_f64());
    std::hint::black_box((tr.n_equiv(), &m2l));
}
