//! Contact repulsion between the membranes of different cells.
//!
//! Vertices `i` of cell `a` and `j` of cell `b ≠ a` closer than `r_c` (minimum image in the
//! periodic box) repel each other with the DPD conservative force and nothing else:
//!
//! ```text
//! F_ij = a_c (1 − r/r_c) e,   e = (x_i − x_j) / r,   F_ji = −F_ij
//! ```
//!
//! ([`super::suspension::CouplingParams::contact_a`]). Vertices of the same cell do not feel
//! it (their membrane forces hold the cell together).
//!
//! [`add_contact_forces`] lists the pairs of cells whose bounding boxes come within `r_c`, sums
//! each pair's forces in parallel (only over the vertices of each cell that lie within `r_c`
//! of the other's box), and adds the sums pair by pair in the order of a serial loop over
//! `(a, b)`, so the forces are the same bit for bit on any number of threads.
//! [`add_contact_forces_all_pairs`] is the reference: every vertex pair of every pair of cells.

use rayon::prelude::*;

use super::pair_force::minimum_image;

/// One cell's vertex positions.
pub type Vertices<'a> = &'a [[f64; 3]];

/// One cell's vertex forces, added to.
pub type VertexForces<'a> = &'a mut [[f64; 3]];

/// Forces of one pair of cells `(a, b)`: `(vertex, force)` on `a`'s vertices and on `b`'s.
type PairForces = (Vec<(u32, [f64; 3])>, Vec<(u32, [f64; 3])>);

/// Lower and upper corners of the bounding box of `x` (unwrapped coordinates).
pub(super) fn bbox(x: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Centre and half-extents of the bounding box of `x`.
fn centred_box(x: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let (lo, hi) = bbox(x);
    (
        [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k])),
        [0, 1, 2].map(|k| 0.5 * (hi[k] - lo[k])),
    )
}

/// Adds the contact forces between the vertices `xs[c]` of different cells to `fs[c]`
/// (`fs[c].len() == xs[c].len()`), in the periodic box `box_len` with cut-off `rc` and
/// amplitude `a`. Cells in parallel; the result does not depend on the thread count.
pub fn add_contact_forces(
    xs: &[Vertices<'_>],
    fs: &mut [VertexForces<'_>],
    box_len: [f64; 3],
    rc: f64,
    a: f64,
) {
    let nc = xs.len();
    if a == 0.0 || nc < 2 {
        return;
    }
    let boxes: Vec<([f64; 3], [f64; 3])> = xs.iter().map(|x| centred_box(x)).collect();
    // Pairs whose boxes (nearest images) come within r_c.
    let pairs: Vec<(usize, usize)> = (0..nc)
        .into_par_iter()
        .flat_map_iter(|i| {
            let boxes = &boxes;
            (i + 1..nc).filter_map(move |j| {
                let (ci, hi) = boxes[i];
                let (cj, hj) = boxes[j];
                let d = minimum_image(ci, cj, box_len);
                (0..3)
                    .all(|k| d[k].abs() <= hi[k] + hj[k] + rc)
                    .then_some((i, j))
            })
        })
        .collect();
    let forces: Vec<PairForces> = pairs
        .par_iter()
        .map(|&(i, j)| pair_forces(xs[i], xs[j], boxes[i], boxes[j], box_len, rc, a))
        .collect();
    for (&(i, j), (fi, fj)) in pairs.iter().zip(&forces) {
        for &(v, f) in fi {
            let t = &mut fs[i][v as usize];
            for k in 0..3 {
                t[k] += f[k];
            }
        }
        for &(v, f) in fj {
            let t = &mut fs[j][v as usize];
            for k in 0..3 {
                t[k] += f[k];
            }
        }
    }
}

/// Vertices of `x` whose nearest image lies within `rc` of the box `(c, h)`. A vertex within
/// `rc` of any point of any image of the box passes, since along each axis the nearest image of
/// the box's centre is at least as close as the image that point belongs to: no pair within
/// `rc` is lost, for any box size.
fn near_box(x: &[[f64; 3]], (c, h): ([f64; 3], [f64; 3]), box_len: [f64; 3], rc: f64) -> Vec<u32> {
    x.iter()
        .enumerate()
        .filter(|(_, p)| {
            let d = minimum_image(**p, c, box_len);
            (0..3).all(|k| d[k].abs() <= h[k] + rc)
        })
        .map(|(v, _)| v as u32)
        .collect()
}

/// The forces between cells `x` and `y` (boxes `bx`, `by`), summed per vertex.
///
/// Only the vertices of each cell within `rc` of the other's box take part. Where the periodic
/// box is wide enough (`2h + rc < L/2` along every axis, `h` the half-extents of `x`'s box),
/// the pair vectors are taken in one frame centred on `x`'s box (then they are the minimum
/// images) and `y`'s vertices are binned in cubes of side `≥ rc`, so each vertex of `x` meets
/// only the vertices of `y` in the 27 cubes around it; otherwise every selected pair is tried
/// with the minimum image.
fn pair_forces(
    x: &[[f64; 3]],
    y: &[[f64; 3]],
    bx: ([f64; 3], [f64; 3]),
    by: ([f64; 3], [f64; 3]),
    box_len: [f64; 3],
    rc: f64,
    a: f64,
) -> PairForces {
    let sx = near_box(x, by, box_len, rc);
    let sy = near_box(y, bx, box_len, rc);
    let mut fy = vec![[0.0; 3]; sy.len()];
    let mut out_x = Vec::new();
    let mut add = |d: [f64; 3], fi: &mut [f64; 3], t: usize| -> bool {
        let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if r2 >= rc * rc || r2 == 0.0 {
            return false;
        }
        let r = r2.sqrt();
        let fm = a * (1.0 - r / rc) / r;
        for k in 0..3 {
            fi[k] += fm * d[k];
            fy[t][k] -= fm * d[k];
        }
        true
    };
    let (c, h) = bx;
    if (0..3).all(|k| 2.0 * h[k] + rc < 0.5 * box_len[k]) && !sy.is_empty() {
        let bins = Bins::new(&sy, y, c, h, box_len, rc);
        for &i in &sx {
            let di = [0, 1, 2].map(|k| x[i as usize][k] - c[k]);
            let b = bins.bin_of(di);
            let mut fi = [0.0; 3];
            let mut touched = false;
            for iz in b[2].saturating_sub(1)..(b[2] + 2).min(bins.n[2]) {
                for iy in b[1].saturating_sub(1)..(b[1] + 2).min(bins.n[1]) {
                    for ix in b[0].saturating_sub(1)..(b[0] + 2).min(bins.n[0]) {
                        let cell = (iz * bins.n[1] + iy) * bins.n[0] + ix;
                        for &t in &bins.order[bins.starts[cell]..bins.starts[cell + 1]] {
                            let e = bins.local[t as usize];
                            let d = [di[0] - e[0], di[1] - e[1], di[2] - e[2]];
                            touched |= add(d, &mut fi, t as usize);
                        }
                    }
                }
            }
            if touched {
                out_x.push((i, fi));
            }
        }
    } else {
        for &i in &sx {
            let mut fi = [0.0; 3];
            let mut touched = false;
            for (t, &j) in sy.iter().enumerate() {
                let d = minimum_image(x[i as usize], y[j as usize], box_len);
                touched |= add(d, &mut fi, t);
            }
            if touched {
                out_x.push((i, fi));
            }
        }
    }
    let out_y = sy
        .iter()
        .zip(&fy)
        .filter(|(_, f)| f.iter().any(|&v| v != 0.0))
        .map(|(&j, &f)| (j, f))
        .collect();
    (out_x, out_y)
}

/// The selected vertices of one cell, in a frame centred on the other cell's box and sorted
/// into cubes covering that box grown by `rc`.
struct Bins {
    /// Positions relative to the centre (nearest images), in selection order.
    local: Vec<[f64; 3]>,
    /// Lower corner of the binned region and the side of a cube (`≥ rc`).
    lo: [f64; 3],
    side: f64,
    /// Cubes per axis.
    n: [usize; 3],
    /// Selection indices sorted by cube (x fastest), and each cube's start in `order`.
    order: Vec<u32>,
    starts: Vec<usize>,
}

impl Bins {
    fn new(
        sel: &[u32],
        y: &[[f64; 3]],
        c: [f64; 3],
        h: [f64; 3],
        box_len: [f64; 3],
        rc: f64,
    ) -> Bins {
        let local: Vec<[f64; 3]> = sel
            .iter()
            .map(|&j| minimum_image(y[j as usize], c, box_len))
            .collect();
        let lo = h.map(|v| -(v + rc));
        // Cubes of side rc, larger where that would make many more cubes than vertices.
        let volume: f64 = h.iter().map(|v| 2.0 * (v + rc)).product();
        let side = rc.max((volume / (4.0 * sel.len() as f64)).cbrt());
        let n = h.map(|v| ((2.0 * (v + rc) / side).ceil() as usize).max(1));
        let mut bins = Bins {
            local,
            lo,
            side,
            n,
            order: Vec::new(),
            starts: vec![0; n[0] * n[1] * n[2] + 1],
        };
        let cells: Vec<usize> = bins
            .local
            .iter()
            .map(|&e| {
                let b = bins.bin_of(e);
                (b[2] * n[1] + b[1]) * n[0] + b[0]
            })
            .collect();
        for &k in &cells {
            bins.starts[k + 1] += 1;
        }
        for k in 0..bins.starts.len() - 1 {
            bins.starts[k + 1] += bins.starts[k];
        }
        let mut next = bins.starts.clone();
        bins.order = vec![0; cells.len()];
        for (t, &k) in cells.iter().enumerate() {
            bins.order[next[k]] = t as u32;
            next[k] += 1;
        }
        bins
    }

    /// The cube of a point of the local frame (clamped to the region).
    fn bin_of(&self, e: [f64; 3]) -> [usize; 3] {
        [0, 1, 2].map(|k| {
            let b = ((e[k] - self.lo[k]) / self.side).floor();
            (b.max(0.0) as usize).min(self.n[k] - 1)
        })
    }
}

/// Reference for [`add_contact_forces`]: every vertex pair of every pair of cells, serially.
pub fn add_contact_forces_all_pairs(
    xs: &[Vertices<'_>],
    fs: &mut [VertexForces<'_>],
    box_len: [f64; 3],
    rc: f64,
    a: f64,
) {
    for i in 0..xs.len() {
        for j in i + 1..xs.len() {
            for (u, xu) in xs[i].iter().enumerate() {
                for (v, xv) in xs[j].iter().enumerate() {
                    let d = minimum_image(*xu, *xv, box_len);
                    let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                    if r2 >= rc * rc || r2 == 0.0 {
                        continue;
                    }
                    let r = r2.sqrt();
                    let fm = a * (1.0 - r / rc) / r;
                    for k in 0..3 {
                        fs[i][u][k] += fm * d[k];
                        fs[j][v][k] -= fm * d[k];
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::assert_close;
    use rand::{Rng, SeedableRng};

    /// Cells as blobs of points (radius ~1.2) centred on a lattice with spacing ~2.2 plus
    /// jitter, so that neighbours touch; some straddle the periodic boundary.
    fn blobs(seed: u64, n_cells: usize, per_cell: usize, box_len: [f64; 3]) -> Vec<Vec<[f64; 3]>> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n_cells)
            .map(|c| {
                let centre = [
                    (c % 3) as f64 * 2.2 + rng.random_range(-0.3..0.3) - 0.5,
                    ((c / 3) % 3) as f64 * 2.2 + rng.random_range(-0.3..0.3),
                    (c / 9) as f64 * 2.2 + rng.random_range(-0.3..0.3) + box_len[2] - 1.0,
                ];
                (0..per_cell)
                    .map(|_| {
                        let u: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
                        let n = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt().max(1e-3);
                        let r = 1.2 * rng.random_range(0.9..1.0);
                        [0, 1, 2].map(|k| centre[k] + r * u[k] / n)
                    })
                    .collect()
            })
            .collect()
    }

    fn forces(
        cells: &[Vec<[f64; 3]>],
        box_len: [f64; 3],
        f: fn(&[Vertices<'_>], &mut [VertexForces<'_>], [f64; 3], f64, f64),
    ) -> Vec<[f64; 3]> {
        let xs: Vec<&[[f64; 3]]> = cells.iter().map(|c| c.as_slice()).collect();
        let mut out: Vec<Vec<[f64; 3]>> = cells
            .iter()
            .map(|c| c.iter().map(|p| [p[0].sin(), p[1].cos(), 0.1]).collect())
            .collect();
        let mut fs: Vec<&mut [[f64; 3]]> = out.iter_mut().map(|c| c.as_mut_slice()).collect();
        f(&xs, &mut fs, box_len, 0.8, 25.0);
        out.into_iter().flatten().collect()
    }

    fn flat(v: &[[f64; 3]]) -> Vec<f64> {
        v.iter().flatten().copied().collect()
    }

    /// The pairwise-pruned parallel sum against every vertex pair, across the periodic
    /// boundary, with forces already present.
    #[test]
    fn contact_forces_equal_the_all_pairs_sum() {
        for (seed, box_len) in [
            (1, [20.0, 20.0, 20.0]),
            (2, [7.0, 8.0, 30.0]),
            (3, [4.0; 3]),
        ] {
            let cells = blobs(seed, 12, 150, box_len);
            let fast = forces(&cells, box_len, add_contact_forces);
            let naive = forces(&cells, box_len, add_contact_forces_all_pairs);
            let none = forces(&cells, box_len, |_, _, _, _, _| {});
            // The contact must act: at least a few hundred vertices feel it.
            let changed = fast.iter().zip(&none).filter(|(a, b)| a != b).count();
            assert!(changed > 100, "only {changed} vertices in contact");
            assert_close("contact forces", &flat(&fast), &flat(&naive), 1e-13);
        }
    }

    /// Thread count does not change a bit of the result.
    #[test]
    fn contact_forces_do_not_depend_on_the_thread_count() {
        let box_len = [7.0, 8.0, 30.0];
        let cells = blobs(4, 14, 120, box_len);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| forces(&cells, box_len, add_contact_forces))
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert_eq!(one, run(2));
    }
}
