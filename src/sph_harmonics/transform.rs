//! Batched forward and inverse spherical-harmonic transforms and grid derivatives.
//!
//! Grid values `f(θ_i, φ_k)` of a batch of `nf` functions (each `2p(p+1)` values, latitude-major,
//! functions one after another) are mapped to coefficients (each [`CoefLayout::len`] values,
//! functions one after another) and back.
//!
//! **Forward**: a real FFT of length `2p` along every latitude gives, per order `m`, the cosine
//! and sine parts `c_m(θ_i)`, `s_m(θ_i)`; then per `m` one GEMM with the analysis matrix
//! `L_m[n, i] = σ_m w_i P̄_n^m(x_i)` (Gauss–Legendre weights `w_i`, `σ_m` the basis and FFT
//! normalisation) maps the `p+1` latitudes of all functions in a block to the degrees `n = m..=p`.
//! The Gauss rule is exact for these products, so the transform is exact (to round-off) for
//! band-limited functions.
//!
//! **Inverse / derivatives**: per `m`, GEMMs with the synthesis matrices `P̄_n^m(x_i)`,
//! `∂_θ P̄_n^m(x_i)`, `∂_θθ P̄_n^m(x_i)`, then an inverse real FFT per latitude; `∂_φ` multiplies the
//! Fourier coefficient of order `m` by `i m` (the Nyquist term `m = p` has a `φ`-derivative
//! `∝ sin(pφ)` that vanishes on every node, so it is exactly zero on the grid).
//!
//! Functions are processed in blocks small enough for the scratch to stay in cache; the plan is
//! immutable and shareable, and each thread passes its own [`ShWorkspace`] (nothing allocates in
//! the transforms). The batched layout follows MOBO (Veerapaneni et al., J. Comput. Phys. 230,
//! 2011): columns of many surfaces side by side so that the Legendre step is GEMM-bound.

use std::f64::consts::PI;
use std::sync::Arc;
use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use super::grid::Grid;
use super::layout::CoefLayout;
use super::legendre::{legendre_derivative_tables, tri_index, tri_len};
use super::SphError;

/// A quantity the inverse transform can produce on the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Deriv {
    /// `f`
    Value,
    /// `∂f/∂θ`
    Theta,
    /// `∂f/∂φ`
    Phi,
    /// `∂²f/∂θ²`
    ThetaTheta,
    /// `∂²f/∂θ∂φ`
    ThetaPhi,
    /// `∂²f/∂φ²`
    PhiPhi,
}

impl Deriv {
    /// All six, in the order value, θ, φ, θθ, θφ, φφ.
    pub const ALL: [Deriv; 6] = [
        Deriv::Value,
        Deriv::Theta,
        Deriv::Phi,
        Deriv::ThetaTheta,
        Deriv::ThetaPhi,
        Deriv::PhiPhi,
    ];
    /// Number of `θ` derivatives (which synthesis matrix is used).
    fn theta_order(self) -> usize {
        match self {
            Deriv::Value | Deriv::Phi | Deriv::PhiPhi => 0,
            Deriv::Theta | Deriv::ThetaPhi => 1,
            Deriv::ThetaTheta => 2,
        }
    }
    /// Number of `φ` derivatives.
    fn phi_order(self) -> usize {
        match self {
            Deriv::Value | Deriv::Theta | Deriv::ThetaTheta => 0,
            Deriv::Phi | Deriv::ThetaPhi => 1,
            Deriv::PhiPhi => 2,
        }
    }
}

/// Precomputed plan for transforms of order `p`.
///
/// A band-limited function (degree `≤ p`, without `Y_p^{-p}`) is recovered exactly, to
/// round-off: forward from its grid values gives its coefficients, inverse gives the grid
/// values back. Here the grid values are summed term by term from the closed-form basis of
/// [`super::reference`], independently of the transform:
///
/// ```
/// use mobo::sph_harmonics::{reference::ylm, ShTransform};
/// let sht = ShTransform::new(10).unwrap();
/// let mut ws = sht.workspace();
/// // Coefficients of a band-limited function, from a fixed pseudo-random sequence.
/// let modes = sht.layout().modes();
/// let mut s = 1u64;
/// let coefs: Vec<f64> = modes
///     .iter()
///     .map(|_| {
///         s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
///         (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
///     })
///     .collect();
/// // Its values on the grid: `Σ a_nm Y_n^m(θ_j, φ_j)`, term by term.
/// let grid = sht.grid();
/// let f: Vec<f64> = (0..grid.n_points())
///     .map(|j| {
///         let (theta, phi) = grid.angles(j);
///         modes.iter().zip(&coefs).map(|(&(n, m), a)| a * ylm(n, m, theta, phi)).sum()
///     })
///     .collect();
/// // Forward: the coefficients back.
/// let mut a = vec![0.0; sht.n_coefs()];
/// sht.forward(&f, &mut a, &mut ws).unwrap();
/// assert!(a.iter().zip(&coefs).all(|(x, y)| (x - y).abs() < 1e-12));
/// // Inverse: the grid values back.
/// let mut back = vec![0.0; f.len()];
/// sht.inverse(&a, &mut back, &mut ws).unwrap();
/// assert!(back.iter().zip(&f).all(|(x, y)| (x - y).abs() < 1e-12));
/// ```
pub struct ShTransform {
    grid: Grid,
    layout: CoefLayout,
    /// Per `m`: analysis matrix, `(p+1−m) × (p+1)`, column-major.
    analysis: Vec<Vec<f64>>,
    /// Per `θ`-derivative order `0, 1, 2`, per `m`: synthesis matrix `(p+1) × (p+1−m)`, column-major.
    synthesis: [Vec<Vec<f64>>; 3],
    fft_fwd: Arc<dyn Fft<f64>>,
    fft_inv: Arc<dyn Fft<f64>>,
    block: usize,
}

/// Scratch space for one thread's transforms with one plan.
pub struct ShWorkspace {
    p: usize,
    block: usize,
    /// Per `θ`-derivative order: per `m` a cosine and a sine matrix `(p+1) × block`.
    spec: [Vec<f64>; 3],
    /// Rings of a block packed two per complex FFT.
    fft_buf: Vec<Complex<f64>>,
    fft_scratch: Vec<Complex<f64>>,
    /// Accumulated time in each phase since the workspace was made or last reset.
    pub timings: PhaseTimings,
}

/// Seconds spent in each phase of the transforms (accumulated over calls).
#[derive(Clone, Copy, Debug, Default)]
pub struct PhaseTimings {
    /// FFTs along latitudes, including packing into and out of the GEMM layout.
    pub fft_s: f64,
    /// Legendre GEMMs.
    pub gemm_s: f64,
}

impl ShTransform {
    /// Plan for order `p ≥ 1`.
    pub fn new(p: usize) -> Result<Self, SphError> {
        if p == 0 {
            return Err(SphError::InvalidOrder(p));
        }
        let grid = Grid::new(p);
        let layout = CoefLayout::new(p);
        let nlat = p + 1;
        let mut val = vec![0.0; tri_len(p)];
        let mut d1 = vec![0.0; tri_len(p)];
        let mut d2 = vec![0.0; tri_len(p)];
        let mut analysis: Vec<Vec<f64>> = (0..=p).map(|m| vec![0.0; (p + 1 - m) * nlat]).collect();
        let mut synthesis: [Vec<Vec<f64>>; 3] =
            std::array::from_fn(|_| (0..=p).map(|m| vec![0.0; (p + 1 - m) * nlat]).collect());
        let pf = p as f64;
        for i in 0..nlat {
            legendre_derivative_tables(
                p,
                grid.cos_theta[i],
                grid.sin_theta[i],
                &mut val,
                &mut d1,
                &mut d2,
            );
            for m in 0..=p {
                let rows = p + 1 - m;
                // Basis normalisation: Y = P̄ trig(mφ) / basis_norm.
                let basis_norm = if m == 0 { (2.0 * PI).sqrt() } else { PI.sqrt() };
                // FFT normalisation: c_m = Re X_m / (2p) for m = 0, p; / p otherwise.
                let fft_norm = if m == 0 || m == p {
                    1.0 / (2.0 * pf)
                } else {
                    1.0 / pf
                };
                // Inverse FFT takes Z_m = (C_m − i S_m)/2 for 0 < m < p.
                let half = if m == 0 || m == p { 1.0 } else { 0.5 };
                for n in m..=p {
                    let t = tri_index(p, n, m);
                    analysis[m][i * rows + (n - m)] =
                        basis_norm * fft_norm * grid.gl_weights[i] * val[t];
                    let s = half / basis_norm;
                    synthesis[0][m][(n - m) * nlat + i] = s * val[t];
                    synthesis[1][m][(n - m) * nlat + i] = s * d1[t];
                    synthesis[2][m][(n - m) * nlat + i] = s * d2[t];
                }
            }
        }
        let mut planner = FftPlanner::<f64>::new();
        let fft_fwd = planner.plan_fft_forward(2 * p);
        let fft_inv = planner.plan_fft_inverse(2 * p);
        // Functions per block: about 64 KiB of spectral scratch per level, so that the packed
        // rings, the spectra and the GEMM operands of a block stay in L2 (tuned with
        // `examples/sht_phases.rs` on a 512 KiB-L2 core: 64 at p = 6, 16 at p = 12…16).
        let block = (4096 / (nlat * nlat)).clamp(8, 128);
        Ok(ShTransform {
            grid,
            layout,
            analysis,
            synthesis,
            fft_fwd,
            fft_inv,
            block,
        })
    }

    /// The order `p`.
    pub fn order(&self) -> usize {
        self.grid.order()
    }
    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    /// The coefficient layout.
    pub fn layout(&self) -> &CoefLayout {
        &self.layout
    }
    /// Grid values per function, `2p(p+1)`.
    pub fn n_points(&self) -> usize {
        self.grid.n_points()
    }
    /// Coefficients per function, `(p+1)² − 1`.
    pub fn n_coefs(&self) -> usize {
        self.layout.len()
    }
    /// Functions per internal block.
    pub fn block_size(&self) -> usize {
        self.block
    }
    /// Set the number of functions per internal block (for tuning; workspaces made before
    /// must be remade).
    pub fn set_block_size(&mut self, block: usize) {
        self.block = block.max(1);
    }

    /// A workspace for this plan.
    pub fn workspace(&self) -> ShWorkspace {
        let p = self.order();
        let level = 2 * (p + 1) * (p + 1) * self.block;
        ShWorkspace {
            p,
            block: self.block,
            spec: std::array::from_fn(|_| vec![0.0; level]),
            fft_buf: vec![Complex::new(0.0, 0.0); (self.block * (p + 1)).div_ceil(2) * 2 * p],
            fft_scratch: vec![
                Complex::new(0.0, 0.0);
                self.fft_fwd
                    .get_inplace_scratch_len()
                    .max(self.fft_inv.get_inplace_scratch_len())
            ],
            timings: PhaseTimings::default(),
        }
    }

    /// Flops of the Legendre GEMMs of one forward (or one value-only inverse) transform of `nf`
    /// functions (`2mnk` per GEMM).
    pub fn legendre_flops(&self, nf: usize) -> f64 {
        let p = self.order();
        let mut f = 0.0;
        for m in 0..=p {
            let cols = if m == 0 || m == p { 1.0 } else { 2.0 };
            f += 2.0 * ((p + 1 - m) * (p + 1)) as f64 * cols;
        }
        f * nf as f64
    }

    fn check_batch(&self, grid_len: usize, coef_len: usize) -> Result<usize, SphError> {
        self.check_batch_in(grid_len, coef_len, self.n_coefs())
    }

    /// [`Self::check_batch`] for `nc` coefficients per function.
    fn check_batch_in(
        &self,
        grid_len: usize,
        coef_len: usize,
        nc: usize,
    ) -> Result<usize, SphError> {
        let np = self.n_points();
        if !grid_len.is_multiple_of(np) {
            return Err(SphError::GridLength {
                len: grid_len,
                per_function: np,
            });
        }
        let nf = grid_len / np;
        if coef_len != nf * nc {
            return Err(SphError::CoefLength {
                len: coef_len,
                expected: nf * nc,
            });
        }
        Ok(nf)
    }

    fn check_workspace(&self, ws: &ShWorkspace) -> Result<(), SphError> {
        if ws.p != self.order() || ws.block != self.block {
            return Err(SphError::Workspace);
        }
        Ok(())
    }

    /// Forward transform of a batch: `grid` holds `nf · 2p(p+1)` values, `coefs` receives
    /// `nf · ((p+1)² − 1)` coefficients.
    pub fn forward(
        &self,
        grid: &[f64],
        coefs: &mut [f64],
        ws: &mut ShWorkspace,
    ) -> Result<(), SphError> {
        self.forward_to(&self.layout, grid, coefs, ws)
    }

    /// The forward transform truncated to the degrees `n ≤ t` of a lower order `t ≤ p`:
    /// `coefs` receives `nf · lay.len()` coefficients in the layout `lay` of order `t` (the
    /// projections onto those basis functions, exact for band-limited functions as
    /// [`Self::forward`]; `Y_t^{-t}`, which that layout leaves out, is dropped). Only the
    /// Legendre work of the kept degrees is done.
    pub fn forward_to(
        &self,
        lay: &CoefLayout,
        grid: &[f64],
        coefs: &mut [f64],
        ws: &mut ShWorkspace,
    ) -> Result<(), SphError> {
        self.check_order(lay)?;
        let nf = self.check_batch_in(grid.len(), coefs.len(), lay.len())?;
        self.check_workspace(ws)?;
        let np = self.n_points();
        let nc = lay.len();
        let mut f0 = 0;
        while f0 < nf {
            let b = self.block.min(nf - f0);
            self.forward_block(
                lay,
                &grid[f0 * np..(f0 + b) * np],
                &mut coefs[f0 * nc..(f0 + b) * nc],
                ws,
            );
            f0 += b;
        }
        Ok(())
    }

    /// Error unless `lay` is of an order `t ≤ p`.
    fn check_order(&self, lay: &CoefLayout) -> Result<(), SphError> {
        if lay.order() > self.order() {
            return Err(SphError::LayoutOrder {
                order: lay.order(),
                transform: self.order(),
            });
        }
        Ok(())
    }

    fn forward_block(
        &self,
        lay: &CoefLayout,
        grid: &[f64],
        coefs: &mut [f64],
        ws: &mut ShWorkspace,
    ) {
        let p = self.order();
        let pt = lay.order();
        let nlat = p + 1;
        let nlon = 2 * p;
        let np = self.n_points();
        let nc = lay.len();
        let b = grid.len() / np;
        let level = nlat * self.block;
        let t0 = Instant::now();
        let spec = &mut ws.spec[0];
        // Two real rings per complex FFT: z = x_a + i x_b, all rings of the block in one call.
        let rings = b * nlat;
        let pairs = rings.div_ceil(2);
        let buf = &mut ws.fft_buf[..pairs * nlon];
        for (pr, z) in buf.chunks_exact_mut(nlon).enumerate() {
            let xa = &grid[2 * pr * nlon..(2 * pr + 1) * nlon];
            if 2 * pr + 1 < rings {
                let xb = &grid[(2 * pr + 1) * nlon..(2 * pr + 2) * nlon];
                for ((z, &a), &b) in z.iter_mut().zip(xa).zip(xb) {
                    *z = Complex::new(a, b);
                }
            } else {
                for (z, &a) in z.iter_mut().zip(xa) {
                    *z = Complex::new(a, 0.0);
                }
            }
        }
        self.fft_fwd.process_with_scratch(buf, &mut ws.fft_scratch);
        // Split: X_a[m] = (Z_m + conj Z_{N−m})/2, X_b[m] = (Z_m − conj Z_{N−m})/(2i). The
        // spectral column of ring r = j·(p+1) + i is r itself; the orders are split one at a
        // time over all ring pairs (the spectra written in their storage order).
        let full = rings / 2;
        for m in 0..=pt {
            let off = 2 * m * level;
            let (cos, sin) = spec[off..off + 2 * level].split_at_mut(level);
            let split = |z: &[Complex<f64>]| -> [f64; 4] {
                let zm = z[m];
                let zc = z[(nlon - m) % nlon].conj();
                // (zm − zc)/(2i) = (Δim, −Δre)/2
                [
                    0.5 * (zm.re + zc.re),
                    -0.5 * (zm.im + zc.im),
                    0.5 * (zm.im - zc.im),
                    0.5 * (zm.re - zc.re),
                ]
            };
            for ((z, c2), s2) in buf
                .chunks_exact(nlon)
                .zip(cos[..2 * full].chunks_exact_mut(2))
                .zip(sin[..2 * full].chunks_exact_mut(2))
            {
                let [ca, sa, cb, sb] = split(z);
                c2[0] = ca;
                s2[0] = sa;
                c2[1] = cb;
                s2[1] = sb;
            }
            if rings % 2 == 1 {
                let [ca, sa, _, _] = split(&buf[full * nlon..(full + 1) * nlon]);
                cos[rings - 1] = ca;
                sin[rings - 1] = sa;
            }
        }
        let t1 = Instant::now();
        for m in 0..=pt {
            // The first `pt + 1 − m` degrees of the analysis matrix of order m.
            let (all, rows) = (p + 1 - m, pt + 1 - m);
            let lhs = MatRef::from_column_major_slice_with_stride(
                &self.analysis[m][..(nlat - 1) * all + rows],
                rows,
                nlat,
                all,
            );
            let emit = |src_off: usize, dst_off: usize, coefs: &mut [f64]| {
                let rhs =
                    MatRef::from_column_major_slice(&spec[src_off..src_off + nlat * b], nlat, b);
                let end = (b - 1) * nc + dst_off + rows;
                let dst = MatMut::from_column_major_slice_with_stride_mut(
                    &mut coefs[dst_off..end],
                    rows,
                    b,
                    nc,
                );
                matmul(dst, Accum::Replace, lhs, rhs, 1.0, Par::Seq);
            };
            emit(2 * m * level, lay.cos_block(m), coefs);
            if let Some(sb) = lay.sin_block(m) {
                emit(2 * m * level + level, sb, coefs);
            }
        }
        let t2 = Instant::now();
        ws.timings.fft_s += (t1 - t0).as_secs_f64();
        ws.timings.gemm_s += (t2 - t1).as_secs_f64();
    }

    /// Inverse transform of a batch (grid values from coefficients).
    pub fn inverse(
        &self,
        coefs: &[f64],
        grid: &mut [f64],
        ws: &mut ShWorkspace,
    ) -> Result<(), SphError> {
        self.synthesize(coefs, &[Deriv::Value], &mut [grid], ws)
    }

    /// Grid values of the requested derivatives of a batch of expansions: `outs[d]` receives
    /// `derivs[d]` for every function (each `nf · 2p(p+1)` values).
    pub fn synthesize(
        &self,
        coefs: &[f64],
        derivs: &[Deriv],
        outs: &mut [&mut [f64]],
        ws: &mut ShWorkspace,
    ) -> Result<(), SphError> {
        self.synthesize_from(&self.layout, coefs, derivs, outs, ws)
    }

    /// [`Self::synthesize`] of expansions of a lower order `t ≤ p` (coefficients in the layout
    /// `lay` of order `t`) on this transform's grid: the upsampling of band-limited functions,
    /// with only the Legendre work of their degrees done.
    pub fn synthesize_from(
        &self,
        lay: &CoefLayout,
        coefs: &[f64],
        derivs: &[Deriv],
        outs: &mut [&mut [f64]],
        ws: &mut ShWorkspace,
    ) -> Result<(), SphError> {
        self.check_order(lay)?;
        if derivs.len() != outs.len() {
            return Err(SphError::OutputCount {
                derivs: derivs.len(),
                outputs: outs.len(),
            });
        }
        let nc = lay.len();
        if !coefs.len().is_multiple_of(nc) {
            return Err(SphError::CoefLength {
                len: coefs.len(),
                expected: (coefs.len() / nc) * nc,
            });
        }
        let nf = coefs.len() / nc;
        for o in outs.iter() {
            self.check_batch_in(o.len(), coefs.len(), nc)?;
        }
        self.check_workspace(ws)?;
        let np = self.n_points();
        let mut f0 = 0;
        while f0 < nf {
            let b = self.block.min(nf - f0);
            self.synthesize_block(
                lay,
                &coefs[f0 * nc..(f0 + b) * nc],
                derivs,
                outs,
                f0 * np,
                ws,
            );
            f0 += b;
        }
        Ok(())
    }

    fn synthesize_block(
        &self,
        lay: &CoefLayout,
        coefs: &[f64],
        derivs: &[Deriv],
        outs: &mut [&mut [f64]],
        out_off: usize,
        ws: &mut ShWorkspace,
    ) {
        let p = self.order();
        let pt = lay.order();
        let nlat = p + 1;
        let nlon = 2 * p;
        let nc = lay.len();
        let b = coefs.len() / nc;
        let level = nlat * self.block;
        let mut needed = [false; 3];
        for d in derivs {
            needed[d.theta_order()] = true;
        }
        let t0 = Instant::now();
        for (t, spec) in ws.spec.iter_mut().enumerate() {
            if !needed[t] {
                continue;
            }
            for m in pt + 1..=p {
                // Orders above the expansion's: no content.
                spec[2 * m * level..2 * m * level + level + nlat * b].fill(0.0);
            }
            for m in 0..=pt {
                // The first `pt + 1 − m` degrees of the synthesis matrix of order m.
                let rows = pt + 1 - m;
                let lhs = MatRef::from_column_major_slice(
                    &self.synthesis[t][m][..nlat * rows],
                    nlat,
                    rows,
                );
                let emit = |src_off: usize, dst_off: usize, spec: &mut [f64]| {
                    let end = (b - 1) * nc + src_off + rows;
                    let rhs = MatRef::from_column_major_slice_with_stride(
                        &coefs[src_off..end],
                        rows,
                        b,
                        nc,
                    );
                    let dst = MatMut::from_column_major_slice_mut(
                        &mut spec[dst_off..dst_off + nlat * b],
                        nlat,
                        b,
                    );
                    matmul(dst, Accum::Replace, lhs, rhs, 1.0, Par::Seq);
                };
                emit(lay.cos_block(m), 2 * m * level, spec);
                match lay.sin_block(m) {
                    Some(sb) => emit(sb, 2 * m * level + level, spec),
                    None => spec[2 * m * level + level..2 * m * level + level + nlat * b].fill(0.0),
                }
            }
        }
        let t1 = Instant::now();
        let rings = b * nlat;
        let pairs = rings.div_ceil(2);
        for (d, out) in derivs.iter().zip(outs.iter_mut()) {
            let spec = &ws.spec[d.theta_order()];
            let k = d.phi_order();
            // Spectrum of ring r (column r of the spectral matrices) at order m: the complex
            // value (C_m, −S_m) times the φ-derivative's factor (i m)^k; the Nyquist term of an
            // odd φ-derivative is ∝ sin(pφ) and vanishes at every node.
            let factor = |m: usize| -> (f64, f64) {
                let mf = m as f64;
                match k {
                    0 => (1.0, 0.0),
                    1 => (0.0, mf),
                    _ => (-mf * mf, 0.0),
                }
            };
            let nyquist = match k {
                1 => 0.0,
                _ => factor(p).0,
            };
            let mtop = pt.min(p - 1);
            let buf = &mut ws.fft_buf[..pairs * nlon];
            // Z = X_a + i X_b with Hermitian X_a, X_b: x_a = Re ifft(Z), x_b = Im ifft(Z). The
            // orders are packed one at a time over all ring pairs (the spectra are read in
            // their storage order, ring by ring).
            let full = rings / 2;
            for (pr, z) in buf.chunks_exact_mut(nlon).enumerate() {
                let (ra, rb) = (2 * pr, 2 * pr + 1);
                let has_b = rb < rings;
                // Order 0 (real; zero under a φ-derivative).
                z[0] = match (k, has_b) {
                    (0, true) => Complex::new(spec[ra], spec[rb]),
                    (0, false) => Complex::new(spec[ra], 0.0),
                    _ => Complex::new(0.0, 0.0),
                };
                if pt < p {
                    // Orders above the expansion's are zero.
                    z[pt + 1..nlon - pt].fill(Complex::new(0.0, 0.0));
                } else {
                    let off = 2 * p * level;
                    let bn = if has_b { spec[off + rb] } else { 0.0 };
                    z[p] = Complex::new(nyquist * spec[off + ra], nyquist * bn);
                }
            }
            for m in 1..mtop + 1 {
                let off = 2 * m * level;
                let (fr, fi) = factor(m);
                let cos = &spec[off..off + rings];
                let sin = &spec[off + level..off + level + rings];
                // a = (C_a − i S_a)(fr + i fi), b likewise; z_m = a + i b, z_{N−m} = conj(a) + i conj(b).
                let pack = |cr: f64, sr: f64, dr: f64, tr: f64| -> (Complex<f64>, Complex<f64>) {
                    let (ci, di) = (-sr, -tr);
                    let (ar, ai) = (cr * fr - ci * fi, cr * fi + ci * fr);
                    let (br, bi) = (dr * fr - di * fi, dr * fi + di * fr);
                    (
                        Complex::new(ar - bi, ai + br),
                        Complex::new(ar + bi, br - ai),
                    )
                };
                for (pr, (c2, s2)) in cos[..2 * full]
                    .chunks_exact(2)
                    .zip(sin[..2 * full].chunks_exact(2))
                    .enumerate()
                {
                    let (zm, zn) = pack(c2[0], s2[0], c2[1], s2[1]);
                    buf[pr * nlon + m] = zm;
                    buf[pr * nlon + nlon - m] = zn;
                }
                if rings % 2 == 1 {
                    let ra = rings - 1;
                    let (zm, zn) = pack(cos[ra], sin[ra], 0.0, 0.0);
                    buf[full * nlon + m] = zm;
                    buf[full * nlon + nlon - m] = zn;
                }
            }
            self.fft_inv.process_with_scratch(buf, &mut ws.fft_scratch);
            let dst = &mut out[out_off..out_off + rings * nlon];
            for (pr, z) in buf.chunks_exact(nlon).enumerate() {
                let ra = 2 * pr;
                for (x, zv) in dst[ra * nlon..(ra + 1) * nlon].iter_mut().zip(z) {
                    *x = zv.re;
                }
                if ra + 1 < rings {
                    for (x, zv) in dst[(ra + 1) * nlon..(ra + 2) * nlon].iter_mut().zip(z) {
                        *x = zv.im;
                    }
                }
            }
        }
        ws.timings.gemm_s += (t1 - t0).as_secs_f64();
        ws.timings.fft_s += t1.elapsed().as_secs_f64();
    }

    /// [`forward`](Self::forward) with the batch split over rayon threads (one workspace each).
    pub fn forward_par(&self, grid: &[f64], coefs: &mut [f64]) -> Result<(), SphError> {
        self.check_batch(grid.len(), coefs.len())?;
        let (np, nc, blk) = (self.n_points(), self.n_coefs(), self.block);
        grid.par_chunks(blk * np)
            .zip(coefs.par_chunks_mut(blk * nc))
            .try_for_each_init(|| self.workspace(), |ws, (g, c)| self.forward(g, c, ws))
    }

    /// [`inverse`](Self::inverse) with the batch split over rayon threads.
    pub fn inverse_par(&self, coefs: &[f64], grid: &mut [f64]) -> Result<(), SphError> {
        self.check_batch(grid.len(), coefs.len())?;
        let (np, nc, blk) = (self.n_points(), self.n_coefs(), self.block);
        coefs
            .par_chunks(blk * nc)
            .zip(grid.par_chunks_mut(blk * np))
            .try_for_each_init(|| self.workspace(), |ws, (c, g)| self.inverse(c, g, ws))
    }
}
