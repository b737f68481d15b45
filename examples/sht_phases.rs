//! Time split of batched transforms: `cargo run --release --example sht_phases -- P SURFACES`.
use mobo::sph_harmonics::ShTransform;
use std::time::Instant;
fn main() {
    let a: Vec<usize> = std::env::args()
        .skip(1)
        .map(|s| s.parse().unwrap())
        .collect();
    let (p, ns) = (
        a.first().copied().unwrap_or(16),
        a.get(1).copied().unwrap_or(10_000),
    );
    let mut sht = ShTransform::new(p).unwrap();
    if let Some(&b) = a.get(2) {
        sht.set_block_size(b);
    }
    let nf = 3 * ns;
    let mut grid: Vec<f64> = (0..nf * sht.n_points())
        .map(|i| ((i % 97) as f64).sin())
        .collect();
    let mut coefs = vec![0.0; nf * sht.n_coefs()];
    let mut ws = sht.workspace();
    sht.forward(&grid, &mut coefs, &mut ws).unwrap();
    ws.timings = Default::default();
    let reps = 5;
    let t = Instant::now();
    for _ in 0..reps {
        sht.forward(&grid, &mut coefs, &mut ws).unwrap();
        sht.inverse(&coefs, &mut grid, &mut ws).unwrap();
    }
    let total = t.elapsed().as_secs_f64() / reps as f64;
    let flops = 2.0 * sht.legendre_flops(nf);
    let g = ws.timings.gemm_s / reps as f64;
    let f = ws.timings.fft_s / reps as f64;
    println!(
        "p={p} nf={nf} block={}: total {:.2} ms, gemm {:.2} ms ({:.1} GFLOP/s), fft+pack {:.2} ms, end-to-end {:.1} GFLOP/s",
        sht.block_size(), total * 1e3, g * 1e3, flops / g / 1e9, f * 1e3, flops / total / 1e9
    );
}
