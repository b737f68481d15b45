//! Rotations that carry a grid point to the north pole.
//!
//! For the target `x_t = (θ_i, φ_k)` of the order-`p` grid let `Q = R_z(φ_k) R_y(θ_i)`, the rotation
//! that maps the north pole to `x_t`. The rotated function `g(y) = f(Q y)` has `g(north) = f(x_t)`,
//! and singular quadrature around `x_t` becomes quadrature around the pole of `g`. Both
//! algorithms return `g` on the grid of order `q ≥ p` (rotate at `p`, evaluate at `q`).
//!
//! * [`DirectRotation`]: per latitude `i` one dense matrix `M_i` (`2q(q+1) × 2p(p+1)`) with
//!   `g = M_i S_k f`, where `S_k` shifts the longitudes of the grid values by `k` (the rotation
//!   `R_z(φ_k)` maps the grid onto itself). `M_i = E_i F`: `F` the forward transform, `E_i` the
//!   basis evaluated at the rotated points `R_y(θ_i) y_j`. `O(p⁴)` work per target: this is the
//!   variant MOBO uses for its dense operators (Veerapaneni et al. 2011, Table II).
//! * [`ShRotation`]: in coefficient space. `R_z(φ_k)` is a phase shift of each order `m`; the
//!   rotation about `y` acts on each degree `n` by an orthogonal `(2n+1) × (2n+1)` block,
//!   `[U_β] = Jᵀ Z(β) J`, with `Z(β)` a rotation about `z` and `J` the fixed block of the
//!   quarter turn `X = R_x(−π/2)` (which maps the `z` axis to the `y` axis, so
//!   `R_y(β) = X R_z(β) Xᵀ`); `J` is computed once by exact quadrature. Then an inverse transform
//!   at order `q`. `O(p³)` per target plus the transform.
//!
//! Convention: for a rotation `Q` the operator `(V_Q h)(y) = h(Q y)` has the coefficient matrix
//! `[V_Q]_{ab} = ∫ Y_a(y) Y_b(Q y) dA`, and `[V_{Q₁Q₂}] = [V_{Q₂}] [V_{Q₁}]`.

use std::sync::{Arc, Mutex, Weak};

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::basis::{angles_of, eval_basis, BasisScratch};
use super::grid::Grid;
use super::layout::CoefLayout;
use super::transform::{ShTransform, ShWorkspace};
use super::SphError;

/// `R_y(β) v`.
pub fn rotate_y(beta: f64, v: [f64; 3]) -> [f64; 3] {
    let (s, c) = beta.sin_cos();
    [c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]]
}

/// `R_z(α) v`.
pub fn rotate_z(alpha: f64, v: [f64; 3]) -> [f64; 3] {
    let (s, c) = alpha.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
}

/// Copy grid values with longitudes shifted by `k`: `out(i, l) = f(i, l + k mod 2p)`, for a batch.
pub fn shift_longitudes(p: usize, k: usize, src: &[f64], dst: &mut [f64]) {
    let nlon = 2 * p;
    let k = k % nlon;
    for (s, d) in src.chunks_exact(nlon).zip(dst.chunks_exact_mut(nlon)) {
        d[..nlon - k].copy_from_slice(&s[k..]);
        d[nlon - k..].copy_from_slice(&s[..k]);
    }
}

/// The rotation matrices of every source latitude (absent: not built).
type Matrices = Vec<Option<Vec<f64>>>;
/// Live matrices per `(p, q)`.
type MatrixCache = Vec<((usize, usize), Weak<Matrices>)>;

/// Direct rotation: one dense matrix per latitude of the source grid.
pub struct DirectRotation {
    p: usize,
    q: usize,
    /// Per source latitude: `M_i`, `n_q × n_p`, column-major (absent if not built). Shared by
    /// every rotation of the same `(p, q)` in the process (they depend on nothing else).
    matrices: Arc<Matrices>,
    shifted: Vec<f64>,
}

impl DirectRotation {
    /// All `p+1` matrices, rotating order-`p` data onto the order-`q` grid. The matrices are
    /// built once per `(p, q)` and shared while any rotation of that pair is alive (a
    /// suspension of many cells holds one copy: 39 MB at `p = 12, q = 24`, not one per cell).
    pub fn new(p: usize, q: usize) -> Result<Self, SphError> {
        static CACHE: Mutex<MatrixCache> = Mutex::new(Vec::new());
        let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
        cache.retain(|(_, w)| w.strong_count() > 0);
        if let Some(m) = cache
            .iter()
            .find(|(k, _)| *k == (p, q))
            .and_then(|(_, w)| w.upgrade())
        {
            return Ok(DirectRotation {
                p,
                q,
                matrices: m,
                shifted: Vec::new(),
            });
        }
        let r = Self::for_latitudes(p, q, &(0..=p).collect::<Vec<_>>())?;
        cache.push(((p, q), Arc::downgrade(&r.matrices)));
        Ok(r)
    }

    /// Only the matrices of the given source latitudes (the others return an error).
    pub fn for_latitudes(p: usize, q: usize, lats: &[usize]) -> Result<Self, SphError> {
        if q < p {
            return Err(SphError::UpsampleOrder { p, q });
        }
        let src = ShTransform::new(p)?;
        let np = src.n_points();
        let nc = src.n_coefs();
        // Forward matrix F (nc × np), column j = coefficients of the j-th unit grid vector.
        let mut eye = vec![0.0; np * np];
        for j in 0..np {
            eye[j * np + j] = 1.0;
        }
        let mut fwd = vec![0.0; nc * np];
        let mut ws = src.workspace();
        src.forward(&eye, &mut fwd, &mut ws)?;
        drop(eye);
        let dst_grid = Grid::new(q);
        let pts = dst_grid.unit_points();
        let nq = pts.len();
        let mut matrices = vec![None; p + 1];
        let mut et = vec![0.0; nc * nq]; // Eᵀ, nc × nq column-major
        let mut scratch = BasisScratch::new(p);
        for &i in lats {
            if i > p {
                return Err(SphError::Latitude { lat: i, p });
            }
            let beta = src.grid().theta[i];
            for (j, &y) in pts.iter().enumerate() {
                let (th, ph) = angles_of(rotate_y(beta, y));
                eval_basis(
                    src.layout(),
                    th,
                    ph,
                    &mut scratch,
                    &mut et[j * nc..(j + 1) * nc],
                );
            }
            let mut m = vec![0.0; nq * np];
            matmul(
                MatMut::from_column_major_slice_mut(&mut m, nq, np),
                Accum::Replace,
                MatRef::from_column_major_slice(&et, nc, nq).transpose(),
                MatRef::from_column_major_slice(&fwd, nc, np),
                1.0,
                Par::Seq,
            );
            matrices[i] = Some(m);
        }
        Ok(DirectRotation {
            p,
            q,
            matrices: Arc::new(matrices),
            shifted: Vec::new(),
        })
    }

    /// Bytes held by the matrices (shared with the other rotations of the same `(p, q)`).
    pub fn memory_bytes(&self) -> usize {
        self.matrices.iter().flatten().map(|m| m.len() * 8).sum()
    }

    /// The matrix of latitude `i` (`n_q × n_p`, column-major).
    pub fn matrix(&self, i: usize) -> Option<&[f64]> {
        self.matrices.get(i).and_then(|m| m.as_deref())
    }

    /// Rotate a batch of order-`p` grid functions so that target `(i, k)` moves to the north
    /// pole; `out` receives the order-`q` grid values of every function.
    pub fn apply(
        &mut self,
        lat: usize,
        lon: usize,
        grid: &[f64],
        out: &mut [f64],
    ) -> Result<(), SphError> {
        let np = 2 * self.p * (self.p + 1);
        let nq = 2 * self.q * (self.q + 1);
        let nf = grid.len() / np;
        if grid.len() != nf * np || out.len() != nf * nq {
            return Err(SphError::GridLength {
                len: grid.len(),
                per_function: np,
            });
        }
        let m = self
            .matrices
            .get(lat)
            .and_then(|m| m.as_deref())
            .ok_or(SphError::Latitude { lat, p: self.p })?;
        self.shifted.resize(grid.len(), 0.0);
        shift_longitudes(self.p, lon, grid, &mut self.shifted);
        matmul(
            MatMut::from_column_major_slice_mut(out, nq, nf),
            Accum::Replace,
            MatRef::from_column_major_slice(m, nq, np),
            MatRef::from_column_major_slice(&self.shifted, np, nf),
            1.0,
            Par::Seq,
        );
        Ok(())
    }
}

/// Per-degree blocks of an orthogonal operator, degree-major: block `n` is `(2n+1)²`,
/// column-major, local index `n + m` for `m = −n..=n`.
fn block_offset(n: usize) -> usize {
    // Σ_{k<n} (2k+1)² = n(2n−1)(2n+1)/3
    if n == 0 {
        0
    } else {
        n * (2 * n - 1) * (2 * n + 1) / 3
    }
}

/// `[V_{R_z(β)}]` for degree `n` (local ordering), column-major `(2n+1)²`.
fn z_block(n: usize, beta: f64, out: &mut [f64]) {
    let d = 2 * n + 1;
    out[..d * d].fill(0.0);
    out[n * d + n] = 1.0;
    for m in 1..=n {
        let (s, c) = (m as f64 * beta).sin_cos();
        let (ic, is) = (n + m, n - m);
        // c' = c cos mβ + s sin mβ ; s' = −c sin mβ + s cos mβ
        out[ic * d + ic] = c;
        out[is * d + ic] = s;
        out[ic * d + is] = -s;
        out[is * d + is] = c;
    }
}

/// Rotation in coefficient space with per-degree blocks.
pub struct ShRotation {
    p: usize,
    q: usize,
    layout: CoefLayout,
    /// The layout of order `p + 1`: every degree `n ≤ p` with all its orders (`Y_p^{-p}`
    /// included), the output of the rotations of a whole latitude.
    wide: CoefLayout,
    /// `(sin mφ_k, cos mφ_k)`, `m = 0 … p` for every longitude `k` (row `k`).
    phase: Vec<(f64, f64)>,
    /// (degree-major local index, layout index) of every `Y_n^m`, `n ≤ p`, in the order-`q`
    /// layout and in `wide`.
    map_q: Vec<(usize, usize)>,
    map_wide: Vec<(usize, usize)>,
    dst: ShTransform,
    dst_ws: ShWorkspace,
    /// Per source latitude: all degree blocks of `[U_{θ_i}]`.
    blocks: Vec<Vec<f64>>,
    buf_in: Vec<f64>,
    buf_out: Vec<f64>,
    coefs_q: Vec<f64>,
}

impl ShRotation {
    /// Rotation of order-`p` expansions onto the order-`q` grid (`q ≥ p`).
    pub fn new(p: usize, q: usize) -> Result<Self, SphError> {
        if q < p {
            return Err(SphError::UpsampleOrder { p, q });
        }
        let src_grid = Grid::new(p);
        let layout = CoefLayout::new(p);
        let jblocks = quarter_turn_blocks(p);
        let mut blocks = Vec::with_capacity(p + 1);
        let total = block_offset(p + 1);
        let mut z = vec![0.0; (2 * p + 1) * (2 * p + 1)];
        let mut zj = vec![0.0; (2 * p + 1) * (2 * p + 1)];
        for &theta in &src_grid.theta {
            let mut b = vec![0.0; total];
            for n in 0..=p {
                let d = 2 * n + 1;
                let off = block_offset(n);
                let j = MatRef::from_column_major_slice(&jblocks[off..off + d * d], d, d);
                z_block(n, theta, &mut z);
                matmul(
                    MatMut::from_column_major_slice_mut(&mut zj[..d * d], d, d),
                    Accum::Replace,
                    MatRef::from_column_major_slice(&z[..d * d], d, d),
                    j,
                    1.0,
                    Par::Seq,
                );
                matmul(
                    MatMut::from_column_major_slice_mut(&mut b[off..off + d * d], d, d),
                    Accum::Replace,
                    j.transpose(),
                    MatRef::from_column_major_slice(&zj[..d * d], d, d),
                    1.0,
                    Par::Seq,
                );
            }
            blocks.push(b);
        }
        let dst = ShTransform::new(q)?;
        let dst_ws = dst.workspace();
        let wide = CoefLayout::new(p + 1);
        let phase = src_grid
            .phi
            .iter()
            .flat_map(|&phi| (0..=p).map(move |m| (m as f64 * phi).sin_cos()))
            .collect();
        Ok(ShRotation {
            p,
            q,
            layout,
            map_q: local_to(p, dst.layout()),
            map_wide: local_to(p, &wide),
            wide,
            phase,
            dst,
            dst_ws,
            blocks,
            buf_in: Vec::new(),
            buf_out: Vec::new(),
            coefs_q: Vec::new(),
        })
    }

    /// Bytes held by the blocks.
    pub fn memory_bytes(&self) -> usize {
        self.blocks.iter().map(|b| b.len() * 8).sum()
    }

    /// Rotated coefficients (order `q` layout) of a batch of order-`p` coefficient vectors.
    pub fn rotate_coefs(
        &mut self,
        lat: usize,
        lon: usize,
        coefs: &[f64],
        out: &mut [f64],
    ) -> Result<(), SphError> {
        self.rotate_coefs_at(lat, lon..lon + 1, coefs, false, out)
    }

    /// [`Self::rotate_coefs`] for every longitude `k = 0 … 2p−1` of latitude `lat` at once:
    /// `out` holds the batch rotated for longitude `k` in functions `k·nf … k·nf + nf − 1`
    /// (`nf` the number of functions in `coefs`), in the layout of order `p + 1` (the degrees
    /// `≤ p` of a rotated expansion, `Y_p^{-p}` included; [`super::ShTransform::synthesize_from`]
    /// puts them on any grid of order `> p`).
    pub fn rotate_coefs_every_longitude(
        &mut self,
        lat: usize,
        coefs: &[f64],
        out: &mut [f64],
    ) -> Result<(), SphError> {
        self.rotate_coefs_at(lat, 0..2 * self.p, coefs, true, out)
    }

    /// The transpose of [`Self::rotate_coefs_every_longitude`], per function: `coefs_q`
    /// (layout of order `p + 1`, `2p·per_lon` functions, function `g` belonging to longitude
    /// `g / per_lon`) is mapped to `out` (order-`p` layout, as many functions) by
    /// `out_g = Φ_kᵀ U_iᵀ Lᵀ g`, where the rotation of longitude `k` is `L U_i Φ_k` (`Φ_k` the
    /// phase shift of every order, `U_i` the degree blocks of latitude `i`, `L` the copy into
    /// the wider layout; `Lᵀ` ignores degree `p + 1`). So for a row vector `r` of
    /// coefficients, `r · rotate(c) = adjoint(r) · c` for every `c` of order `p`:
    /// the layer potentials use it to carry kernel rows back to the unrotated coefficients
    /// ([`crate::vesicle::SelfInteraction::assemble`]).
    pub fn adjoint_every_longitude(
        &mut self,
        lat: usize,
        per_lon: usize,
        coefs_q: &[f64],
        out: &mut [f64],
    ) -> Result<(), SphError> {
        let (p, lp) = (self.p, self.layout.len());
        let lq = self.wide.len();
        let nf = 2 * p * per_lon;
        if coefs_q.len() != nf * lq {
            return Err(SphError::CoefLength {
                len: coefs_q.len(),
                expected: nf * lq,
            });
        }
        if out.len() != nf * lp {
            return Err(SphError::CoefLength {
                len: out.len(),
                expected: nf * lp,
            });
        }
        if lat > p {
            return Err(SphError::Latitude { lat, p });
        }
        if nf == 0 {
            return Ok(());
        }
        let nloc = (p + 1) * (p + 1);
        self.buf_in.resize(nloc * nf, 0.0);
        self.buf_out.resize(nloc * nf, 0.0);
        // Lᵀ: gather the degrees n ≤ p into the degree-major local order.
        for (c, col) in coefs_q
            .chunks_exact(lq)
            .zip(self.buf_in.chunks_exact_mut(nloc))
        {
            col.fill(0.0);
            for &(l, ix) in &self.map_wide {
                col[l] = c[ix];
            }
        }
        // U_iᵀ, one GEMM per degree over all functions.
        self.blocks_times(lat, nf, true);
        // Φ_kᵀ: the transposed phase shift into the order-p layout.
        for k in 0..2 * p {
            let phase = &self.phase[k * (p + 1)..(k + 1) * (p + 1)];
            for f in k * per_lon..(k + 1) * per_lon {
                let h = &self.buf_out[f * nloc..(f + 1) * nloc];
                let o = &mut out[f * lp..(f + 1) * lp];
                for n in 0..=p {
                    let base = n * n + n;
                    o[self.layout.cos_block(0) + n] = h[base];
                    for m in 1..=n {
                        let (s, co) = phase[m];
                        let (hc, hs) = (h[base + m], h[base - m]);
                        o[self.layout.cos_block(m) + n - m] = hc * co - hs * s;
                        if let Some(b) = self.layout.sin_block(m) {
                            o[b + n - m] = hc * s + hs * co;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// The layout of order `p + 1` of [`Self::rotate_coefs_every_longitude`]'s output and
    /// [`Self::adjoint_every_longitude`]'s input.
    pub fn wide_layout(&self) -> &CoefLayout {
        &self.wide
    }

    /// `buf_out = U · buf_in` (or `Uᵀ · buf_in`) per degree for `nf` functions in the
    /// degree-major local order.
    fn blocks_times(&mut self, lat: usize, nf: usize, transpose: bool) {
        let nloc = (self.p + 1) * (self.p + 1);
        let blocks = &self.blocks[lat];
        for n in 0..=self.p {
            let d = 2 * n + 1;
            let off = block_offset(n);
            let row0 = n * n;
            let src = &self.buf_in[row0..];
            let src = MatRef::from_column_major_slice_with_stride(
                &src[..(nf - 1) * nloc + d],
                d,
                nf,
                nloc,
            );
            let end = (nf - 1) * nloc + row0 + d;
            let dst = MatMut::from_column_major_slice_with_stride_mut(
                &mut self.buf_out[row0..end],
                d,
                nf,
                nloc,
            );
            let u = MatRef::from_column_major_slice(&blocks[off..off + d * d], d, d);
            matmul(
                dst,
                Accum::Replace,
                if transpose { u.transpose() } else { u },
                src,
                1.0,
                Par::Seq,
            );
        }
    }

    /// [`Self::rotate_coefs`] for a range of longitudes of one latitude (the `j`-th longitude
    /// of the range into functions `j·nf …`), into the layout `wide` or (`false`) that of
    /// order `q`.
    fn rotate_coefs_at(
        &mut self,
        lat: usize,
        lons: std::ops::Range<usize>,
        coefs: &[f64],
        wide: bool,
        out: &mut [f64],
    ) -> Result<(), SphError> {
        let (p, lp) = (self.p, self.layout.len());
        let lq = if wide {
            self.wide.len()
        } else {
            self.dst.n_coefs()
        };
        let nf = coefs.len() / lp;
        let nt = nf * lons.len();
        if coefs.len() != nf * lp || out.len() != nt * lq {
            return Err(SphError::CoefLength {
                len: coefs.len(),
                expected: nf * lp,
            });
        }
        if lat > p || lons.end > 2 * p {
            return Err(SphError::Latitude { lat, p });
        }
        if nt == 0 {
            return Ok(());
        }
        let nloc = (p + 1) * (p + 1);
        self.buf_in.resize(nloc * nt, 0.0);
        self.buf_out.resize(nloc * nt, 0.0);
        // Gather into degree-major blocks: degree n occupies rows n²..(n+1)² of a
        // (p+1)² × nt matrix, phase-shifted by R_z(φ_k) ((sin mφ, cos mφ) once per longitude).
        for (j, lon) in lons.enumerate() {
            let phase = &self.phase[lon * (p + 1)..(lon + 1) * (p + 1)];
            for (f, c) in coefs.chunks_exact(lp).enumerate() {
                let g = j * nf + f;
                let col = &mut self.buf_in[g * nloc..(g + 1) * nloc];
                for n in 0..=p {
                    let base = n * n + n;
                    col[base] = c[self.layout.cos_block(0) + n];
                    for m in 1..=n {
                        let cv = c[self.layout.cos_block(m) + n - m];
                        let sv = self.layout.sin_block(m).map_or(0.0, |b| c[b + n - m]);
                        let (s, co) = phase[m];
                        col[base + m] = cv * co + sv * s;
                        col[base - m] = -cv * s + sv * co;
                    }
                }
            }
        }
        self.blocks_times(lat, nt, false);
        // Scatter: local (degree-major) index → output layout index.
        let map = if wide { &self.map_wide } else { &self.map_q };
        for (o, col) in out
            .chunks_exact_mut(lq)
            .zip(self.buf_out.chunks_exact(nloc))
        {
            o.fill(0.0);
            for &(l, ix) in map {
                o[ix] = col[l];
            }
        }
        Ok(())
    }

    /// Rotate a batch of order-`p` coefficient vectors so that target `(lat, lon)` moves to the
    /// north pole; `out` receives the order-`q` grid values.
    pub fn apply(
        &mut self,
        lat: usize,
        lon: usize,
        coefs: &[f64],
        out: &mut [f64],
    ) -> Result<(), SphError> {
        let nf = coefs.len() / self.layout.len();
        let mut cq = std::mem::take(&mut self.coefs_q);
        cq.resize(nf * self.dst.n_coefs(), 0.0);
        let r = self
            .rotate_coefs(lat, lon, coefs, &mut cq)
            .and_then(|_| self.dst.inverse(&cq, out, &mut self.dst_ws));
        self.coefs_q = cq;
        r
    }

    /// The order of the output grid.
    pub fn output_order(&self) -> usize {
        self.q
    }
}

/// Pairs (degree-major local index, index in `lay`) of every `Y_n^m`, `n ≤ p`, that `lay` holds.
fn local_to(p: usize, lay: &CoefLayout) -> Vec<(usize, usize)> {
    (0..=p)
        .flat_map(|n| {
            let base = n * n + n;
            (-(n as isize)..=(n as isize))
                .filter_map(move |m| lay.index(n, m).map(|ix| ((base as isize + m) as usize, ix)))
        })
        .collect()
}

/// Blocks `J^n = [V_X]` of the quarter turn `X = R_x(−π/2)`, `(x, y, z) ↦ (x, z, −y)`, for
/// `n ≤ p`, by Gauss quadrature of order `p+1` (exact for these degree-`2n` products).
fn quarter_turn_blocks(p: usize) -> Vec<f64> {
    let quad = p + 1;
    let grid = Grid::new(quad);
    let lay = CoefLayout::new(quad);
    let w = grid.quadrature_weights();
    let pts = grid.unit_points();
    let npts = pts.len();
    let nc = lay.len();
    let mut y = vec![0.0; npts * nc]; // per point, all basis functions
    let mut yx = vec![0.0; npts * nc];
    let mut scratch = BasisScratch::new(quad);
    for (j, &v) in pts.iter().enumerate() {
        let (t, f) = grid.angles(j);
        eval_basis(&lay, t, f, &mut scratch, &mut y[j * nc..(j + 1) * nc]);
        let (t2, f2) = angles_of([v[0], v[2], -v[1]]);
        eval_basis(&lay, t2, f2, &mut scratch, &mut yx[j * nc..(j + 1) * nc]);
    }
    let mut out = vec![0.0; block_offset(p + 1)];
    let mut a = Vec::new();
    let mut b = Vec::new();
    for n in 0..=p {
        let d = 2 * n + 1;
        let idx: Vec<usize> = (-(n as isize)..=n as isize)
            .map(|m| {
                lay.index(n, m)
                    .expect("degree n ≤ p is complete at order p+1")
            })
            .collect();
        a.clear();
        b.clear();
        // a: d × npts (weighted Y_a), b: npts × d (Y_b ∘ X), both column-major.
        for j in 0..npts {
            for &ia in &idx {
                a.push(w[j] * y[j * nc + ia]);
            }
        }
        for &ib in &idx {
            for j in 0..npts {
                b.push(yx[j * nc + ib]);
            }
        }
        let off = block_offset(n);
        matmul(
            MatMut::from_column_major_slice_mut(&mut out[off..off + d * d], d, d),
            Accum::Replace,
            MatRef::from_column_major_slice(&a, d, npts),
            MatRef::from_column_major_slice(&b, npts, d),
            1.0,
            Par::Seq,
        );
    }
    out
}
