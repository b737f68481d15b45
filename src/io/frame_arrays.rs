//! A frame's cells stacked into the arrays that are written ([`FrameArrays`]): the same
//! arrays in the `.npy` files of [`super::frames`] and in `frames.h5` ([`super::hdf5`]).

/// One cell's state in a frame (borrowed).
#[derive(Clone, Copy, Debug)]
pub struct CellFrame<'a> {
    /// SH order `p`.
    pub order: usize,
    /// `3 · n_coefs` SH coefficients: `x`, then `y`, then `z`.
    pub coefs: &'a [f64],
    /// `3 · n_points` grid positions, component-major.
    pub positions: &'a [f64],
    /// `n_points` tension values on the SH grid.
    pub tension: &'a [f64],
}

/// A frame's cells stacked into the arrays that are written (C order).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameArrays {
    /// Number of cells.
    pub n_cells: usize,
    /// SH order `p`.
    pub order: usize,
    /// `(p+1)² − 1`.
    pub n_coefs: usize,
    /// `2p(p+1)`.
    pub n_points: usize,
    /// `(cells, 3, n_coefs)`.
    pub coefs: Vec<f64>,
    /// `(cells, 3, n_points)`.
    pub positions: Vec<f64>,
    /// `(cells, n_points)`.
    pub tension: Vec<f64>,
}

impl FrameArrays {
    /// Stack the cells, checking that they share one order `p ≥ 1` and that every slice has
    /// its length; the error says which cell and which array is wrong.
    pub fn from_cells(cells: &[CellFrame<'_>]) -> Result<Self, String> {
        let first = cells.first().ok_or("a frame needs at least one cell")?;
        let p = first.order;
        if p == 0 {
            return Err("cell 0 has SH order 0 (must be at least 1)".into());
        }
        let n_coefs = (p + 1) * (p + 1) - 1;
        let n_points = 2 * p * (p + 1);
        let n = cells.len();
        let mut out = FrameArrays {
            n_cells: n,
            order: p,
            n_coefs,
            n_points,
            coefs: Vec::with_capacity(3 * n_coefs * n),
            positions: Vec::with_capacity(3 * n_points * n),
            tension: Vec::with_capacity(n_points * n),
        };
        for (c, cell) in cells.iter().enumerate() {
            if cell.order != p {
                return Err(format!(
                    "cell {c} has SH order {} but cell 0 has {p} (all cells of a frame share one order)",
                    cell.order
                ));
            }
            for (what, len, want) in [
                ("coefficients", cell.coefs.len(), 3 * n_coefs),
                ("grid positions", cell.positions.len(), 3 * n_points),
                ("tension values", cell.tension.len(), n_points),
            ] {
                if len != want {
                    return Err(format!("cell {c} has {len} {what}; order {p} needs {want}"));
                }
            }
            out.coefs.extend_from_slice(cell.coefs);
            out.positions.extend_from_slice(cell.positions);
            out.tension.extend_from_slice(cell.tension);
        }
        Ok(out)
    }

    /// `[cells, 3, n_coefs]`.
    pub fn coefs_shape(&self) -> [usize; 3] {
        [self.n_cells, 3, self.n_coefs]
    }
    /// `[cells, 3, n_points]`.
    pub fn positions_shape(&self) -> [usize; 3] {
        [self.n_cells, 3, self.n_points]
    }
    /// `[cells, n_points]`.
    pub fn tension_shape(&self) -> [usize; 2] {
        [self.n_cells, self.n_points]
    }
}
