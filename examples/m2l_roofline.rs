//! The M2L's Hadamard products against their own roofline, one core (issue: `mobo fmm` as a
//! tool; "M2L at ≥ 50 % of its roofline, GEMM or memory bandwidth").
//!
//! ```text
//! cargo run --release --example m2l_roofline [-- SIDE REPEATS]
//! ```
//!
//! The M2L of [`mobo::fmm::m2l_fft`] multiplies, for every frequency chunk and every
//! (target box, source box) pair of a V list, a `dt × de` block of kernel spectra by the source's
//! spectrum chunk and adds it to the target's: `8 dt de` flops per frequency (complex
//! multiply-add), 32 frequencies per chunk. This runs, on the real kernel spectra at the order
//! of 6 digits, the V lists of one full level of `SIDE³` boxes (default 16: 4096 boxes, the
//! finest level of a uniform 10⁶-point tree at the default leaf size) two ways:
//!
//! * **pairs**: [`FftM2l::accumulate_chunk`] for every pair, sorted by offset then target;
//! * **8 × 8 blocks**: [`FftM2l::accumulate_siblings`] for every pair of neighbouring parents
//!   (the evaluator's default in uniform regions; up to 63 products per block, touching
//!   children skipped, zeros for absent ones), sorted by target, on each SIMD path the CPU
//!   runs ([`SiblingPath`]: the AVX2 loop by target octant, the AVX-512 one by octant
//!   difference; the portable loop only where there is none; the evaluator takes the widest).
//!
//! Rates count the useful flops (the V-list pairs') either way, against faer's one-thread GEMM
//! rate and the one-thread triad bandwidth measured in the same run:
//! `roof = min(GEMM, AI × cache bandwidth)`, the arithmetic intensity from the source and
//! target slices each call streams (a pair: `(de + 2 dt)·2·32·8` bytes; a block: 8 times that
//! for its pairs).
use faer::Par;
use mobo::fmm::calibration::order_for_digits;
use mobo::fmm::evaluator::FmmKernel;
use mobo::fmm::kernels::{Kernel, Laplace, Stokeslet};
use mobo::fmm::m2l_fft::{
    offset_index, parent_offset, parent_offset_index, FftM2l, SiblingPath, CHUNK,
};
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

/// One full level of a uniform tree: `side³` boxes (`side` even) in Morton-like order, the
/// 8 children of a parent in consecutive slots.
struct Lattice {
    side: usize,
}

impl Lattice {
    fn new(side: usize) -> Self {
        Lattice {
            side: side.max(4) / 2 * 2,
        }
    }

    fn boxes(&self) -> usize {
        self.side.pow(3)
    }

    /// Slot of the box at integer position `x`: parent index times 8 plus the octant.
    fn slot(&self, x: [usize; 3]) -> usize {
        let h = self.side / 2;
        let parent = (x[0] / 2 * h + x[1] / 2) * h + x[2] / 2;
        8 * parent + ((x[0] & 1) << 2 | (x[1] & 1) << 1 | (x[2] & 1))
    }

    fn positions(&self) -> impl Iterator<Item = [usize; 3]> + '_ {
        let n = self.side;
        (0..n).flat_map(move |i| (0..n).flat_map(move |j| (0..n).map(move |k| [i, j, k])))
    }

    /// `(target slot, source slot, offset)` of every V-list pair: children of the parent's
    /// colleagues that do not touch the target.
    fn v_pairs(&self) -> impl Iterator<Item = (usize, usize, [i32; 3])> + '_ {
        let n = self.side as i32;
        self.positions().flat_map(move |x| {
            let p = x.map(|c| (c / 2) as i32);
            let mut out = Vec::new();
            for d in 0..27 {
                let q = [0, 1, 2].map(|k| p[k] + parent_offset(d)[k]);
                if q.iter().any(|&c| c < 0 || 2 * c >= n) || q == p {
                    continue;
                }
                for o in 0..8 {
                    let y = [
                        2 * q[0] + (o >> 2 & 1),
                        2 * q[1] + (o >> 1 & 1),
                        2 * q[2] + (o & 1),
                    ];
                    let off = [0, 1, 2].map(|k| x[k] as i32 - y[k]);
                    if off.iter().any(|c| c.abs() >= 2) {
                        out.push((self.slot(x), self.slot(y.map(|c| c as usize)), off));
                    }
                }
            }
            out
        })
    }

    /// `(first target slot, first source slot, parent offset slot)` of every pair of
    /// neighbouring parents, by target.
    fn sibling_blocks(&self) -> Vec<(usize, usize, usize)> {
        let h = (self.side / 2) as i32;
        let mut out = Vec::new();
        for p in 0..h.pow(3) {
            let pp = [p / (h * h), (p / h) % h, p % h];
            for d in (0..27).filter(|&d| d != 13) {
                let q = [0, 1, 2].map(|k| pp[k] + parent_offset(d)[k]);
                if q.iter().any(|&c| c < 0 || c >= h) {
                    continue;
                }
                let qi = (q[0] * h + q[1]) * h + q[2];
                // Parent offset target − source, as a slot of [−1, 1]³.
                let dp = [0, 1, 2].map(|k| pp[k] - q[k]);
                out.push((8 * p as usize, 8 * qi as usize, parent_offset_index(dp)));
            }
        }
        out
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let side: usize = a.first().map_or(Ok(16), |s| s.parse())?;
    let reps: usize = a.get(1).map_or(Ok(3), |s| s.parse())?;
    let gemm = gemm_rate(1024, Par::Seq);
    // Memory (3 × 32 MB) and cache (3 × 2 MB: the size of one chunk's source and target
    // slices here, which stay in the last-level cache while the chunk's pairs run).
    let bw = triad_bandwidth(4 << 20);
    let bw_cache = triad_bandwidth(1 << 18);
    println!(
        "one core: faer GEMM {gemm:.1} GFLOP/s, triad {bw:.1} GB/s (memory), {bw_cache:.1} GB/s \
         (3 × 2 MB, cache); one level of {side}³ boxes, their V lists"
    );
    println!();
    println!("| kernel | order | dt × de | chunks | loop | useful GFLOP/s | % of GEMM | AI (flop/B) | roof min(GEMM, AI × cache) | % of roof | time (s) |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let cases: [(&str, FmmKernel, &dyn Kernel); 2] = [
        ("Laplace", FmmKernel::Laplace, &Laplace),
        ("Stokeslet", FmmKernel::Stokeslet, &Stokeslet),
    ];
    let lattice = Lattice::new(side);
    for (name, fk, ke) in cases {
        let p = order_for_digits(fk, 6)?;
        let m2l = FftM2l::new(ke, &CubeSurface::new(p));
        let (dt, de) = (ke.output_dim(), ke.density_dim());
        let (sl, tl) = (FftM2l::chunk_len(de), FftM2l::chunk_len(dt));
        let (nch, boxes) = (m2l.n_chunks, lattice.boxes());
        let mut rng = StdRng::seed_from_u64(7);
        let src: Vec<f64> = (0..nch * boxes * sl)
            .map(|_| rng.random::<f64>() - 0.5)
            .collect();
        let mut tgt = vec![0.0; nch * boxes * tl];
        // Pairs: (target, source, compact offset), sorted by offset then target.
        let mut pairs: Vec<(u32, u32, u16)> = lattice
            .v_pairs()
            .map(|(t, s, d)| {
                (
                    t as u32,
                    s as u32,
                    m2l.compact_offset(offset_index(d)) as u16,
                )
            })
            .collect();
        pairs.sort_unstable_by_key(|&(t, _, o)| (o, t));
        // Each chunk's kernel spectra are expanded from the base offsets first, as the
        // evaluator does (timed with the products).
        let used = vec![true; m2l.n_offsets()];
        let mut kernels = vec![0.0; m2l.kernel_chunk_len()];
        let pair_secs = best_of(reps, 0.0, || {
            for c in 0..nch {
                m2l.expand_chunk(c, &used, &mut kernels);
                let sc = &src[c * boxes * sl..(c + 1) * boxes * sl];
                let tc = &mut tgt[c * boxes * tl..(c + 1) * boxes * tl];
                for &(ti, si, o) in &pairs {
                    let (ti, si) = (ti as usize, si as usize);
                    m2l.accumulate_chunk(
                        &kernels,
                        o as usize,
                        &sc[si * sl..(si + 1) * sl],
                        &mut tc[ti * tl..(ti + 1) * tl],
                    );
                }
            }
            std::hint::black_box(&tgt);
        });
        // Blocks: (first target slot, first source slot, parent offset slot), by target; on
        // every instruction set this CPU runs (the portable reference only where it is the one).
        let blocks = lattice.sibling_blocks();
        let mut paths = SiblingPath::available();
        if paths.len() > 1 {
            paths.retain(|&p| p != SiblingPath::Portable);
        }
        let block_secs: Vec<(SiblingPath, f64)> = paths
            .into_iter()
            .map(|path| {
                let secs = best_of(reps, 0.0, || {
                    for c in 0..nch {
                        let sc = &src[c * boxes * sl..(c + 1) * boxes * sl];
                        let tc = &mut tgt[c * boxes * tl..(c + 1) * boxes * tl];
                        m2l.expand_chunk(c, &used, &mut kernels);
                        let tables: Vec<[&[f64]; 27]> =
                            (0..27).map(|dp| m2l.sibling_blocks(&kernels, dp)).collect();
                        for &(t0, s0, dp) in &blocks {
                            m2l.accumulate_siblings_on(
                                path,
                                &tables[dp],
                                &sc[s0 * sl..(s0 + 8) * sl],
                                &mut tc[t0 * tl..(t0 + 8) * tl],
                            );
                        }
                    }
                    std::hint::black_box(&tgt);
                });
                (path, secs)
            })
            .collect();
        // Useful flops: the V-list pairs' products, either way.
        let flops = 8.0 * (dt * de * CHUNK) as f64 * (nch * pairs.len()) as f64;
        let pair_ai = (8 * dt * de * CHUNK) as f64 / (8 * (sl + 2 * tl)) as f64;
        // A block streams 8 source and 8 target slices (read and write) for its pairs.
        let block_ai = flops / (nch * blocks.len() * 8 * (8 * (sl + 2 * tl))) as f64;
        let rows = std::iter::once(("pairs".to_string(), pair_secs, pair_ai)).chain(
            block_secs
                .iter()
                .map(|&(path, secs)| (format!("8 × 8 blocks, {path:?}"), secs, block_ai)),
        );
        for (what, secs, ai) in rows {
            let rate = flops / secs / 1e9;
            let roof = gemm.min(ai * bw_cache);
            println!(
                "| {name} | {p} | {dt} × {de} | {nch} | {what} | {rate:.2} | {:.0} % | {ai:.2} | {roof:.2} | {:.0} % | {secs:.3} |",
                100.0 * rate / gemm,
                100.0 * rate / roof
            );
        }
    }
    Ok(())
}
