//! The M2L's Hadamard products against their own roofline, one core (issue: `mobo fmm` as a
//! tool; "M2L at ≥ 50 % of its roofline, GEMM or memory bandwidth").
//!
//! ```text
//! cargo run --release --example m2l_roofline [-- BOXES REPEATS]
//! ```
//!
//! The M2L of [`mobo::fmm::m2l_fft`] multiplies, for every frequency chunk and every
//! (target box, source box) pair of a V list, a `dt × de` block of kernel spectra by the source's
//! spectrum chunk and adds it to the target's: `8 dt de` flops per frequency (complex
//! multiply-add), 32 frequencies per chunk. This runs exactly that loop
//! ([`FftM2l::accumulate_chunk`] over every chunk, pairs sorted by offset then target as the
//! evaluator sorts them) on the real kernel spectra at the order of 6 digits, for `BOXES`
//! targets and sources (default 4096, a level of a 10⁶-point tree) with 189 random V-list
//! partners each, and reports:
//!
//! * the flop rate against faer's one-thread GEMM rate measured in the same run (the compute
//!   roof);
//! * the bytes it streams per call, the source and target chunks (`(de + 2 dt)·2·32·8` bytes;
//!   the kernel block of an offset stays in cache while the pairs of that offset run), against
//!   the one-thread triad bandwidth measured in the same run, from memory and from cache (one
//!   chunk's source and target slices, a few MB, stay in the last-level cache while its pairs
//!   run): `roof = min(GEMM, AI × cache bandwidth)`.
use faer::Par;
use mobo::fmm::calibration::order_for_digits;
use mobo::fmm::evaluator::FmmKernel;
use mobo::fmm::kernels::{Kernel, Laplace, Stokeslet};
use mobo::fmm::m2l_fft::{offset_index, FftM2l, CHUNK};
use mobo::fmm::surface::CubeSurface;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// The benches' timing helpers (best-of-N wall time, faer's GEMM rate).
#[path = "../benches/common/mod.rs"]
mod timing;
use timing::{best_of, gemm_rate};

/// One-thread triad `a = b + s c` over three arrays of `n` values, GB/s (24 bytes per element).
fn triad_bandwidth(n: usize) -> f64 {
    let (b, c) = (vec![1.0f64; n], vec![2.0f64; n]);
    let mut a = vec![0.0f64; n];
    let t = best_of(5, 0.0, || {
        for ((x, y), z) in a.iter_mut().zip(&b).zip(&c) {
            *x = y + 0.5 * z;
        }
        std::hint::black_box(&a);
    });
    24.0 * n as f64 / t / 1e9
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let boxes: usize = a.first().map_or(Ok(4096), |s| s.parse())?;
    let reps: usize = a.get(1).map_or(Ok(3), |s| s.parse())?;
    let gemm = gemm_rate(1024, Par::Seq);
    // Memory (3 × 32 MB) and cache (3 × 2 MB: the size of one chunk's source and target
    // slices here, which stay in the last-level cache while the chunk's pairs run).
    let bw = triad_bandwidth(4 << 20);
    let bw_cache = triad_bandwidth(1 << 18);
    println!(
        "one core: faer GEMM {gemm:.1} GFLOP/s, triad {bw:.1} GB/s (memory), {bw_cache:.1} GB/s \
         (3 × 2 MB, cache); {boxes} target and source boxes, 189 V-list pairs each"
    );
    println!();
    println!("| kernel | order | dt × de | chunks | chunk slices (MB) | GFLOP/s | % of GEMM | AI (flop/B) | AI × memory | AI × cache | roof min(GEMM, AI × cache) | % of roof |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let offsets: Vec<[i32; 3]> = (-3i32..=3)
        .flat_map(|x| (-3i32..=3).flat_map(move |y| (-3i32..=3).map(move |z| [x, y, z])))
        .filter(|d| d[0].abs().max(d[1].abs()).max(d[2].abs()) >= 2)
        .collect();
    let cases: [(&str, FmmKernel, &dyn Kernel); 2] = [
        ("Laplace", FmmKernel::Laplace, &Laplace),
        ("Stokeslet", FmmKernel::Stokeslet, &Stokeslet),
    ];
    for (name, fk, ke) in cases {
        let p = order_for_digits(fk, 6)?;
        let m2l = FftM2l::new(ke, &CubeSurface::new(p));
        let (dt, de) = (ke.output_dim(), ke.density_dim());
        let (sl, tl) = (FftM2l::chunk_len(de), FftM2l::chunk_len(dt));
        let nch = m2l.n_chunks;
        let mut rng = StdRng::seed_from_u64(7);
        // (target, source, compact offset): 189 distinct partners per target.
        let mut pairs: Vec<(u32, u32, u16)> = Vec::with_capacity(boxes * 189);
        for t in 0..boxes {
            for k in 0..189 {
                let o = m2l.compact_offset(offset_index(offsets[(t + k * 5) % offsets.len()]));
                pairs.push((t as u32, rng.random_range(0..boxes) as u32, o as u16));
            }
        }
        pairs.sort_unstable_by_key(|&(t, _, o)| (o, t));
        let src: Vec<f64> = (0..nch * boxes * sl)
            .map(|_| rng.random::<f64>() - 0.5)
            .collect();
        let mut tgt = vec![0.0; nch * boxes * tl];
        let secs = best_of(reps, 0.0, || {
            for c in 0..nch {
                let sc = &src[c * boxes * sl..(c + 1) * boxes * sl];
                let tc = &mut tgt[c * boxes * tl..(c + 1) * boxes * tl];
                for &(ti, si, o) in &pairs {
                    let (ti, si) = (ti as usize, si as usize);
                    m2l.accumulate_chunk(
                        c,
                        o as usize,
                        &sc[si * sl..(si + 1) * sl],
                        &mut tc[ti * tl..(ti + 1) * tl],
                    );
                }
            }
            std::hint::black_box(&tgt);
        });
        let calls = (nch * pairs.len()) as f64;
        let flops = 8.0 * (dt * de * CHUNK) as f64 * calls;
        let rate = flops / secs / 1e9;
        let ai = (8 * dt * de * CHUNK) as f64 / (8 * (sl + 2 * tl)) as f64;
        let roof = gemm.min(ai * bw_cache);
        let slices_mb = (boxes * (sl + tl) * 8) as f64 / 1e6;
        println!(
            "| {name} | {p} | {dt} × {de} | {nch} | {slices_mb:.1} | {rate:.2} | {:.0} % | {ai:.3} | {:.2} | {:.2} | {roof:.2} | {:.0} % |",
            100.0 * rate / gemm,
            ai * bw,
            ai * bw_cache,
            100.0 * rate / roof
        );
    }
    Ok(())
}
