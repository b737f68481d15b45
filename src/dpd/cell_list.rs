//! Cell lists in a periodic box: particles binned into cells of side `≥ r_c` and sorted by
//! cell, so every neighbour within `r_c` of a particle is in its own or one of the 26
//! surrounding cells, and the particles of a cell are contiguous in memory.
//!
//! The sort is a counting sort (`O(N)`, stable): the permutation it returns reorders every
//! per-particle array of the system (structure of arrays), which keeps the pair loop's reads
//! of neighbour cells sequential.

use super::{require, DpdError};

/// The cell grid of a periodic box.
#[derive(Clone, Debug, PartialEq)]
pub struct CellGrid {
    /// Cells per axis (each at least 3, so the 27 neighbour cells are distinct).
    pub dims: [usize; 3],
    /// Box side lengths.
    pub box_len: [f64; 3],
    /// Inverse cell side lengths (`dims / box_len`).
    pub inv_cell: [f64; 3],
}

impl CellGrid {
    /// The grid with the most cells of side at least `rc` (at least 3 per axis).
    pub fn new(box_len: [f64; 3], rc: f64) -> Result<Self, DpdError> {
        require(rc.is_finite() && rc > 0.0, "rc", rc, "must be positive")?;
        let mut dims = [0; 3];
        let mut inv_cell = [0.0; 3];
        for k in 0..3 {
            let l = box_len[k];
            require(
                l.is_finite() && l >= 3.0 * rc,
                "box length",
                l,
                "must be at least 3 rc (the cell list needs 3 cells per axis)",
            )?;
            dims[k] = ((l / rc).floor() as usize).max(3);
            inv_cell[k] = dims[k] as f64 / l;
        }
        require(
            dims.iter().product::<usize>() < u32::MAX as usize,
            "box volume in cells",
            dims.iter().product::<usize>() as f64,
            "too many cells",
        )?;
        Ok(CellGrid {
            dims,
            box_len,
            inv_cell,
        })
    }

    /// Number of cells.
    pub fn n_cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// The cell of a point inside the box (`0 ≤ x < L` per axis; points on the far face are
    /// put in the last cell).
    #[inline]
    pub fn cell_of(&self, p: [f64; 3]) -> usize {
        let c = |k: usize| ((p[k] * self.inv_cell[k]) as usize).min(self.dims[k] - 1);
        (c(2) * self.dims[1] + c(1)) * self.dims[0] + c(0)
    }

    /// Cell coordinates of cell `c`.
    #[inline]
    pub fn coords(&self, c: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [c % nx, (c / nx) % ny, c / (nx * ny)]
    }

    /// The 27 cells around cell `c` (itself included) with the shift to add to a neighbour's
    /// position to bring it next to `c` across the periodic faces.
    pub fn neighbours(&self, c: usize) -> [(usize, [f64; 3]); 27] {
        let mut out = [(0usize, [0.0; 3]); 27];
        let mut m = 0;
        for dz in -1i64..=1 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    out[m] = self.offset_cell(c, [dx, dy, dz]);
                    m += 1;
                }
            }
        }
        out
    }

    /// The half stencil of cell `c`: the 13 of its 26 neighbours "above" it (`dz = 1`; or
    /// `dz = 0, dy = 1`; or `dz = dy = 0, dx = 1`), with their shifts. Every pair of
    /// distinct neighbouring cells is one cell's half neighbour exactly once.
    pub fn half_neighbours(&self, c: usize) -> [(usize, [f64; 3]); 13] {
        let mut out = [(0usize, [0.0; 3]); 13];
        let mut m = 0;
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                out[m] = self.offset_cell(c, [dx, dy, 1]);
                m += 1;
            }
        }
        for dx in -1i64..=1 {
            out[m] = self.offset_cell(c, [dx, 1, 0]);
            m += 1;
        }
        out[m] = self.offset_cell(c, [1, 0, 0]);
        out
    }

    /// The cell at offset `d` (each component in −1..=1) from `c`, wrapped, and the shift.
    #[inline]
    fn offset_cell(&self, c: usize, d: [i64; 3]) -> (usize, [f64; 3]) {
        let cc = self.coords(c);
        let mut idx = [0usize; 3];
        let mut shift = [0.0; 3];
        for k in 0..3 {
            let n = self.dims[k] as i64;
            let v = cc[k] as i64 + d[k];
            let (w, s) = if v < 0 {
                (v + n, -self.box_len[k])
            } else if v >= n {
                (v - n, self.box_len[k])
            } else {
                (v, 0.0)
            };
            idx[k] = w as usize;
            shift[k] = s;
        }
        (
            (idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0],
            shift,
        )
    }
}

/// Particles sorted by cell: cell `c` holds the particles `starts[c]..starts[c + 1]`.
#[derive(Clone, Debug)]
pub struct CellList {
    /// The grid.
    pub grid: CellGrid,
    /// Start of each cell's particles in the sorted order (`n_cells + 1` values).
    pub starts: Vec<usize>,
    /// Scratch: the cell of each particle in the unsorted order.
    unsorted_cell: Vec<u32>,
}

impl CellList {
    /// An empty list on `grid`.
    pub fn new(grid: CellGrid) -> Self {
        let n = grid.n_cells();
        CellList {
            grid,
            starts: vec![0; n + 1],
            unsorted_cell: Vec::new(),
        }
    }

    /// Bin the points (inside the box) and fill `perm` with the stable counting-sort order:
    /// `perm[new] = old`. After it, [`Self::starts`] describes the points
    /// reordered by `perm`.
    pub fn sort(&mut self, x: &[f64], y: &[f64], z: &[f64], perm: &mut Vec<u32>) {
        let n = x.len();
        let nc = self.grid.n_cells();
        use rayon::prelude::*;
        self.unsorted_cell.resize(n, 0);
        let grid = &self.grid;
        self.unsorted_cell
            .par_chunks_mut(16384)
            .enumerate()
            .for_each(|(k, out)| {
                for (m, c) in out.iter_mut().enumerate() {
                    let i = k * 16384 + m;
                    *c = grid.cell_of([x[i], y[i], z[i]]) as u32;
                }
            });
        self.starts.clear();
        self.starts.resize(nc + 1, 0);
        for &c in &self.unsorted_cell {
            self.starts[c as usize + 1] += 1;
        }
        for c in 0..nc {
            self.starts[c + 1] += self.starts[c];
        }
        perm.clear();
        perm.resize(n, 0);
        // Running insertion points, kept in `starts` shifted by one cell, restored below.
        for (i, &c) in self.unsorted_cell.iter().enumerate() {
            let slot = &mut self.starts[c as usize];
            perm[*slot] = i as u32;
            *slot += 1;
        }
        for c in (1..=nc).rev() {
            self.starts[c] = self.starts[c - 1];
        }
        self.starts[0] = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sort_groups_particles_by_cell_stably() {
        let grid = CellGrid::new([4.0, 3.0, 5.0], 1.0).unwrap();
        assert_eq!(grid.dims, [4, 3, 5]);
        let mut list = CellList::new(grid.clone());
        let pts: Vec<[f64; 3]> = (0..200)
            .map(|i| {
                let f = |k: u64, l: f64| {
                    super::super::rng::unit_interval(super::super::rng::stream(9, k, i)) * l
                };
                [f(0, 4.0), f(1, 3.0), f(2, 5.0)]
            })
            .collect();
        let (x, y, z): (Vec<f64>, Vec<f64>, Vec<f64>) = (
            pts.iter().map(|p| p[0]).collect(),
            pts.iter().map(|p| p[1]).collect(),
            pts.iter().map(|p| p[2]).collect(),
        );
        let mut perm = Vec::new();
        list.sort(&x, &y, &z, &mut perm);
        assert_eq!(list.starts[grid.n_cells()], 200);
        let mut seen = [false; 200];
        for c in 0..grid.n_cells() {
            let members = &perm[list.starts[c]..list.starts[c + 1]];
            assert!(members.windows(2).all(|w| w[0] < w[1]), "stable");
            for &old in members {
                assert_eq!(grid.cell_of(pts[old as usize]), c);
                seen[old as usize] = true;
            }
        }
        assert!(seen.iter().all(|&s| s));
    }

    #[test]
    fn neighbours_are_27_distinct_cells_with_periodic_shifts() {
        let grid = CellGrid::new([3.0, 4.0, 6.0], 1.0).unwrap();
        for c in 0..grid.n_cells() {
            let nb = grid.neighbours(c);
            let mut cells: Vec<usize> = nb.iter().map(|n| n.0).collect();
            cells.sort();
            cells.dedup();
            assert_eq!(cells.len(), 27);
            // The shifted neighbour cell's centre is within √3 cells of c's centre.
            let cc = grid.coords(c);
            for (n, s) in nb {
                let nc = grid.coords(n);
                for k in 0..3 {
                    let h = grid.box_len[k] / grid.dims[k] as f64;
                    let d = (nc[k] as f64 * h + s[k]) - cc[k] as f64 * h;
                    assert!(d.abs() < 1.5 * h, "cell {c} neighbour {n} axis {k}: {d}");
                }
            }
        }
        assert!(CellGrid::new([2.5, 4.0, 4.0], 1.0).is_err());
        // Half stencils: every unordered pair of neighbouring distinct cells exactly once.
        let mut pairs = std::collections::HashMap::new();
        for c in 0..grid.n_cells() {
            for (n, _) in grid.half_neighbours(c) {
                assert_ne!(n, c);
                *pairs.entry((c.min(n), c.max(n))).or_insert(0) += 1;
            }
        }
        let mut full = std::collections::HashSet::new();
        for c in 0..grid.n_cells() {
            for (n, _) in grid.neighbours(c) {
                if n != c {
                    full.insert((c.min(n), c.max(n)));
                }
            }
        }
        assert_eq!(pairs.len(), full.len());
        assert!(pairs.values().all(|&k| k == 1));
    }
}
