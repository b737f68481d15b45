//! Speed of the contact repulsion between DPD cells ([`mobo::dpd::contact`]): a packed
//! lattice of RBC meshes (642 vertices each, gaps of 0.3 r_c between neighbours' boxes) in a
//! periodic box. With two cells along an axis of the box the vertices are not binned (the
//! frame of a pair is not one image there), with three or more they are. Times, best of
//! several runs: the serial loop the suspension used before
//! (every pair of cells whose boxes come within r_c, all vertex pairs of it), and
//! `add_contact_forces` on one thread and on all of the machine's; the forces are checked
//! against the serial loop; faer's GEMM rate of the same run is printed beside them (the
//! machine's speed). `cargo bench --bench dpd_contact`.

mod common;

use common::{best_of, gemm_rate};
use mobo::dpd::contact::{
    add_contact_forces, add_contact_forces_all_pairs, VertexForces, Vertices,
};
use mobo::dpd::pair_force::minimum_image;
use mobo::vesicle::{shapes, CellMesh};

type Forces = fn(&[Vertices<'_>], &mut [VertexForces<'_>], [f64; 3], f64, f64);

fn run(cells: &[Vec<[f64; 3]>], l: [f64; 3], f: Forces) -> Vec<Vec<[f64; 3]>> {
    let xs: Vec<&[[f64; 3]]> = cells.iter().map(|c| c.as_slice()).collect();
    let mut out: Vec<Vec<[f64; 3]>> = cells.iter().map(|c| vec![[0.0; 3]; c.len()]).collect();
    let mut fs: Vec<&mut [[f64; 3]]> = out.iter_mut().map(|c| c.as_mut_slice()).collect();
    f(&xs, &mut fs, l, 1.0, 25.0);
    out
}

fn bounds(x: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let lo = [0, 1, 2].map(|k| x.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min));
    let hi = [0, 1, 2].map(|k| x.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max));
    (lo, hi)
}

/// Pairs of cells whose bounding boxes (nearest images) come within `rc`.
fn pairs_in_reach(xs: &[Vertices<'_>], l: [f64; 3], rc: f64) -> Vec<(usize, usize)> {
    let boxes: Vec<_> = xs.iter().map(|x| bounds(x)).collect();
    let mut pairs = Vec::new();
    for i in 0..xs.len() {
        for j in i + 1..xs.len() {
            let ci = [0, 1, 2].map(|k| 0.5 * (boxes[i].0[k] + boxes[i].1[k]));
            let cj = [0, 1, 2].map(|k| 0.5 * (boxes[j].0[k] + boxes[j].1[k]));
            let d = minimum_image(ci, cj, l);
            if (0..3).all(|k| {
                d[k].abs()
                    <= 0.5 * (boxes[i].1[k] - boxes[i].0[k] + boxes[j].1[k] - boxes[j].0[k]) + rc
            }) {
                pairs.push((i, j));
            }
        }
    }
    pairs
}

/// The loop of the suspension before: pairs of cells whose boxes come within r_c, every
/// vertex pair of those, serially.
fn serial_loop(xs: &[Vertices<'_>], fs: &mut [VertexForces<'_>], l: [f64; 3], rc: f64, a: f64) {
    for (i, j) in pairs_in_reach(xs, l, rc) {
        let (left, right) = fs.split_at_mut(j);
        add_contact_forces_all_pairs(
            &[xs[i], xs[j]],
            &mut [&mut *left[i], &mut *right[0]],
            l,
            rc,
            a,
        );
    }
}

fn main() {
    let surface = shapes::rbc(8).unwrap();
    let mesh = CellMesh::icosphere(&surface, 3).unwrap();
    let unit: Vec<[f64; 3]> = mesh.vertices.iter().map(|p| p.map(|v| 3.0 * v)).collect();
    let (lo, hi) = bounds(&unit);
    let gap = 0.3;
    let pitch = [0, 1, 2].map(|k| hi[k] - lo[k] + gap);
    println!(
        "faer's one-thread GEMM in this run: {:.1} GFLOP/s",
        gemm_rate(1024, faer::Par::Seq)
    );
    println!(
        "| cells (lattice) | vertices per cell | pairs of cells in reach | serial loop before (ms) | 1 thread (ms) | {} threads (ms) | speed-up, 1 / {} threads | max rel. difference |",
        rayon::current_num_threads(),
        rayon::current_num_threads()
    );
    println!("|---|---|---|---|---|---|---|---|");
    for n in [[2, 2, 2], [4, 4, 2], [3, 3, 3], [4, 4, 6]] {
        let l = [0, 1, 2].map(|k| n[k] as f64 * pitch[k]);
        let mut cells = Vec::new();
        for a in 0..n[0] {
            for b in 0..n[1] {
                for c in 0..n[2] {
                    let shift = [a, b, c].map(|i| i as f64);
                    cells.push(
                        unit.iter()
                            .map(|p| [0, 1, 2].map(|k| p[k] + shift[k] * pitch[k]))
                            .collect::<Vec<_>>(),
                    );
                }
            }
        }
        let want = run(&cells, l, serial_loop);
        let got = run(&cells, l, add_contact_forces);
        let scale = want
            .iter()
            .flatten()
            .flatten()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = want
            .iter()
            .flatten()
            .flatten()
            .zip(got.iter().flatten().flatten())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            scale > 0.0 && diff <= 1e-12 * scale,
            "forces differ: {diff} of {scale}"
        );
        let xs: Vec<Vertices<'_>> = cells.iter().map(|c| c.as_slice()).collect();
        let pairs = pairs_in_reach(&xs, l, 1.0).len();
        let before = best_of(3, 0.5, || {
            std::hint::black_box(run(&cells, l, serial_loop));
        });
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| {
                best_of(3, 0.5, || {
                    std::hint::black_box(run(&cells, l, add_contact_forces));
                })
            });
        let all = best_of(3, 0.5, || {
            std::hint::black_box(run(&cells, l, add_contact_forces));
        });
        println!(
            "| {} ({}×{}×{}{}) | {} | {pairs} | {:.2} | {:.3} | {:.3} | {:.0}× / {:.0}× | {:.1e} |",
            cells.len(),
            n[0],
            n[1],
            n[2],
            if n.iter().any(|&k| k < 3) {
                ", two along an axis: no binning"
            } else {
                ""
            },
            unit.len(),
            1e3 * before,
            1e3 * one,
            1e3 * all,
            before / one,
            before / all,
            diff / scale
        );
    }
}
