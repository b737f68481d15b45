//! The walls' system split over ranks: each rank holds the rows of a band of the walls' grid.
//!
//! Under `mpirun` a replicated [`super::WallSystem`] costs every rank the whole dense operator
//! (`8 (3N)²` bytes for `N` wall points: 0.8 GB for a tube of order 40) and its factorisation.
//! Split, rank `r` of `P` holds the rows of its band of latitudes
//! ([`RowShare::bands`]), `A_r` (`n_r × n`, about `n²/P` values), and the LU factors of its
//! diagonal block `B_r = A_r[:, rows of r]` (`n_r²`). The system `A ψ = U` is then solved by
//! GMRES over the ranks, right-preconditioned by the block Jacobi `M = diag(B_0, …, B_{P−1})`:
//! each product `A M⁻¹ v` solves the rank's own block, gathers the whole vector
//! ([`WallRows::gather`]) and multiplies its rows ([`WallRows::apply`]). The operator is second
//! kind (`∓½I + K` plus rank-one and rigid-body completions), and the bands keep each point's
//! singular neighbourhood mostly within one block, so the iteration converges in a few steps
//! (one on one rank, where `M = A`). The driver with the ranks' inner products lives with the
//! cells' step ([`crate::timestep`]), which owns the communicator.

use std::ops::Range;

use faer::linalg::matmul::matmul;
use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::{Accum, Mat, MatRef, Par};

use super::{check_len, Wall};

/// Which share of the walls' rows a process holds: rank `rank` of `ranks`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RowShare {
    /// This process's rank.
    pub rank: usize,
    /// The number of ranks the walls are split over.
    pub ranks: usize,
}

/// Latitudes `lats` of wall `wall`'s grid (each latitude `2p` points).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WallBand {
    /// The wall.
    pub wall: usize,
    /// Its latitudes.
    pub lats: Range<usize>,
}

impl WallBand {
    /// The band's grid points on its wall (`2p` a latitude).
    pub fn points(&self, walls: &[Wall]) -> Range<usize> {
        let nlon = 2 * walls[self.wall].order();
        nlon * self.lats.start..nlon * self.lats.end
    }
}

impl RowShare {
    /// One process holding every row.
    pub const WHOLE: RowShare = RowShare { rank: 0, ranks: 1 };

    /// Whether this share is the whole system.
    pub fn is_whole(&self) -> bool {
        self.ranks == 1
    }

    /// This rank's bands: the walls' latitudes in order (wall by wall, pole to pole) cut into
    /// `ranks` contiguous runs of about equal numbers of points. A rank may hold none (more
    /// ranks than latitudes).
    pub fn bands(&self, walls: &[Wall]) -> Vec<WallBand> {
        let total: usize = walls.iter().map(|w| w.n_points()).sum();
        let (lo, hi) = (
            self.rank * total / self.ranks,
            (self.rank + 1) * total / self.ranks,
        );
        let mut bands: Vec<WallBand> = Vec::new();
        let mut start = 0;
        for (k, w) in walls.iter().enumerate() {
            let nlon = 2 * w.order();
            for lat in 0..=w.order() {
                // A latitude belongs to the rank whose run holds its first point.
                if (lo..hi).contains(&start) {
                    match bands.last_mut() {
                        Some(b) if b.wall == k && b.lats.end == lat => b.lats.end += 1,
                        _ => bands.push(WallBand {
                            wall: k,
                            lats: lat..lat + 1,
                        }),
                    }
                }
                start += nlon;
            }
        }
        bands
    }

    /// The unknowns of this rank's rows, in the order of its rows: band by band, each band's
    /// points component by component (`offsets[k] + a·n_k + t`, `offsets` the walls' first
    /// unknowns).
    pub fn unknowns(&self, walls: &[Wall], offsets: &[usize]) -> Vec<usize> {
        let mut out = Vec::new();
        for b in self.bands(walls) {
            let n = walls[b.wall].n_points();
            for a in 0..3 {
                out.extend(b.points(walls).map(|t| offsets[b.wall] + a * n + t));
            }
        }
        out
    }
}

/// One rank's rows of the walls' system and its block-Jacobi preconditioner (module docs).
pub struct WallRows {
    share: RowShare,
    /// Every rank's unknowns, in the order of its rows.
    unknowns: Vec<Vec<usize>>,
    /// This rank's rows `A_r` (`n_r × n`).
    rows: Mat<f64>,
    /// The LU factors of `B_r` (`None` for a rank without rows).
    block: Option<PartialPivLu<f64>>,
    /// Smallest over largest pivot of `B_r`'s factorisation (1 without rows).
    pivot_ratio: f64,
}

impl WallRows {
    /// The rows `rows` of rank `share.rank` (in the order of [`RowShare::unknowns`]) of the
    /// system over `walls` with first unknowns `offsets`; factors the diagonal block.
    pub(super) fn new(share: RowShare, walls: &[Wall], offsets: &[usize], rows: Mat<f64>) -> Self {
        let unknowns: Vec<Vec<usize>> = (0..share.ranks)
            .map(|rank| {
                RowShare {
                    rank,
                    ranks: share.ranks,
                }
                .unknowns(walls, offsets)
            })
            .collect();
        let mine = &unknowns[share.rank];
        let nr = mine.len();
        let (block, pivot_ratio) = if nr == 0 {
            (None, 1.0)
        } else {
            let b = Mat::<f64>::from_fn(nr, nr, |i, j| rows[(i, mine[j])]);
            let lu = b.partial_piv_lu();
            let ratio = crate::lu_pivots::pivot_ratio(lu.U());
            (Some(lu), ratio)
        };
        WallRows {
            share,
            unknowns,
            rows,
            block,
            pivot_ratio,
        }
    }

    /// The share these rows are.
    pub fn share(&self) -> RowShare {
        self.share
    }
    /// Rows held here.
    pub fn n_rows(&self) -> usize {
        self.rows.nrows()
    }
    /// Unknowns of the whole system.
    pub fn n_unknowns(&self) -> usize {
        self.rows.ncols()
    }
    /// Rank `rank`'s unknowns, in the order of its rows.
    pub fn unknowns(&self, rank: usize) -> &[usize] {
        &self.unknowns[rank]
    }
    /// Smallest over largest pivot of the diagonal block's factorisation.
    pub fn pivot_ratio(&self) -> f64 {
        self.pivot_ratio
    }
    /// Bytes of the rows and the block's factors held here.
    pub fn bytes(&self) -> usize {
        let nr = self.n_rows();
        8 * (nr * self.n_unknowns() + nr * nr)
    }

    /// This rank's entries of the whole vector `whole` (its rows' unknowns).
    pub fn restrict(&self, whole: &[f64]) -> Vec<f64> {
        self.unknowns[self.share.rank]
            .iter()
            .map(|&i| whole[i])
            .collect()
    }

    /// The whole vector from every rank's entries (`parts[r]` in the order of rank `r`'s rows,
    /// as an all-gather returns them).
    ///
    /// # Errors
    /// [`super::WallError::Length`] when a part does not match its rank's rows.
    pub fn gather(&self, parts: &[Vec<f64>]) -> Result<Vec<f64>, super::WallError> {
        check_len("ranks' parts", parts.len(), self.share.ranks)?;
        let mut whole = vec![0.0; self.n_unknowns()];
        for (part, idx) in parts.iter().zip(&self.unknowns) {
            check_len("a rank's part of the wall vector", part.len(), idx.len())?;
            for (&i, &v) in idx.iter().zip(part) {
                whole[i] = v;
            }
        }
        Ok(whole)
    }

    /// `y = A_r x`: this rank's rows times the whole vector `x`.
    pub fn apply(&self, x: &[f64], y: &mut [f64]) {
        let (nr, n) = (self.n_rows(), self.n_unknowns());
        debug_assert_eq!((x.len(), y.len()), (n, nr));
        if nr == 0 {
            return;
        }
        matmul(
            faer::MatMut::from_column_major_slice_mut(y, nr, 1),
            Accum::Replace,
            self.rows.as_ref(),
            MatRef::from_column_major_slice(x, n, 1),
            1.0,
            Par::Seq,
        );
    }

    /// `z = B_r⁻¹ v` on this rank's rows (the block-Jacobi preconditioner).
    pub fn precondition(&self, v: &[f64], z: &mut [f64]) {
        z.copy_from_slice(v);
        if let Some(lu) = &self.block {
            let nr = z.len();
            lu.solve_in_place(faer::MatMut::from_column_major_slice_mut(z, nr, 1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::shapes;
    use crate::wall::{WallKind, WallParams, WallSystem};

    /// An ellipsoidal container (order 8) around two spheres (orders 6 and 5).
    fn walls() -> Vec<Wall> {
        let mut a = shapes::sphere(6, 0.7).unwrap();
        a.translate([-1.2, 0.3, 0.0]);
        let mut b = shapes::sphere(5, 0.5).unwrap();
        b.translate([1.3, -0.2, 0.4]);
        vec![
            Wall::new(
                WallKind::Container,
                shapes::ellipsoid(8, [3.0, 2.5, 2.0]).unwrap(),
            )
            .unwrap(),
            Wall::new(WallKind::Body, a).unwrap(),
            Wall::new(WallKind::Body, b).unwrap(),
        ]
    }

    #[test]
    fn the_bands_of_the_ranks_hold_every_unknown_once() {
        let w = walls();
        let mut offsets = vec![0];
        for x in &w {
            offsets.push(offsets.last().unwrap() + 3 * x.n_points());
        }
        let n = *offsets.last().unwrap();
        for ranks in [1, 2, 3, 5, 40] {
            let mut seen = vec![0; n];
            let mut sizes = vec![];
            for rank in 0..ranks {
                let u = RowShare { rank, ranks }.unknowns(&w, &offsets);
                sizes.push(u.len());
                for i in u {
                    seen[i] += 1;
                }
            }
            assert!(seen.iter().all(|&s| s == 1), "{ranks} ranks");
            // Whole latitudes: no rank more than one latitude (3·2p unknowns) past its share.
            if ranks <= 5 {
                let most = *sizes.iter().max().unwrap();
                assert!(most <= n / ranks + 3 * 16, "{ranks} ranks: {sizes:?}");
            }
        }
    }

    /// Every rank's rows, gathered, are the whole operator: the whole system's direct solve of
    /// `A x` (each rank's rows times `x`) gives `x` back; and the block-Jacobi preconditioner
    /// inverts each rank's diagonal block.
    #[test]
    fn the_split_rows_are_the_whole_operator() {
        let params = WallParams::default();
        let whole = WallSystem::new(walls(), params).unwrap();
        let n = whole.n_unknowns();
        // Data without net flux through the container: a rigid translation there.
        let x: Vec<f64> = (0..n)
            .map(|i| ((i as f64) * 0.37).sin() + 0.1 * (i % 7) as f64)
            .collect();
        for ranks in [2, 3] {
            let shares: Vec<WallSystem> = (0..ranks)
                .map(|rank| {
                    WallSystem::new_share(walls(), params, RowShare { rank, ranks }).unwrap()
                })
                .collect();
            let parts: Vec<Vec<f64>> = shares
                .iter()
                .map(|s| {
                    let r = s.rows().expect("split");
                    let mut y = vec![0.0; r.n_rows()];
                    r.apply(&x, &mut y);
                    // The preconditioner solves the diagonal block: B_r (B_r⁻¹ y) = y.
                    let mut z = vec![0.0; r.n_rows()];
                    r.precondition(&y, &mut z);
                    let mut zw = vec![0.0; n];
                    for (&i, &v) in r.unknowns(r.share().rank).iter().zip(&z) {
                        zw[i] = v;
                    }
                    let mut back = vec![0.0; r.n_rows()];
                    r.apply(&zw, &mut back);
                    let scale = y.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
                    let e = back
                        .iter()
                        .zip(&y)
                        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
                    assert!(e <= 1e-12 * scale, "block solve off by {e:.1e}");
                    y
                })
                .collect();
            let ax = shares[0].rows().unwrap().gather(&parts).unwrap();
            // The container's data of `A x` carry the net flux of `x`'s rank-one term; solve
            // the factored whole system as a plain linear system.
            let got = whole.solve_formed(&ax, f64::INFINITY).unwrap();
            let back: Vec<f64> = (0..whole.walls().len())
                .flat_map(|k| got.density(k).to_vec())
                .collect();
            let e = back
                .iter()
                .zip(&x)
                .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
            assert!(e <= 1e-11, "{ranks} ranks: rows give x back to {e:.1e}");
            assert!(
                shares[0].solve(&ax).is_err(),
                "a split system is not solved alone"
            );
        }
    }
}
