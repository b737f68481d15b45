//! Stokes layer potentials on a cell's own surface: pole rotation and the Graham–Sloan rule.
//!
//! For every grid point `x_t` (latitude `i`, longitude `k`) of the order-`p` grid the surface and
//! the density are rotated so that `x_t` sits at the north pole of the parameter sphere
//! ([`crate::sph_harmonics::rotation`], rotation at order `p`, output on the order-`q` grid), and
//! the `1/r`-singular integral is evaluated with the Graham–Sloan weights `ω_i` of order `q`
//! ([`GrahamSloan`]; Graham & Sloan 2002, Veerapaneni et al. 2011):
//!
//! * single layer `S[f](x) = (1/8πμ) ∫ (I/r + r⊗r/r³) f dA ≈ (1/8πμ) Σ_j ω_j J_j (I/r + r⊗r/r³) f_j`,
//! * double layer `D[u](x) = (3/4π) ∫ (r·n)(r⊗r)/r⁵ u dA`, same rule,
//!
//! with `r = x − y_j`, `y_j` the rotated surface on the order-`q` grid, `n` its outward normal and
//! `J = |Y_θ × Y_φ| / sin θ` its area per unit solid angle (computed from the rotated, still
//! band-limited, surface: exact). On a sphere of radius `a`: `S[3μΩ×n/a] = Ω×x`,
//! `S[f] = 2af/3μ` for a uniform `f`, and `D[c] = −c/2` for a constant `c`.
//!
//! Both rotation algorithms are selectable ([`RotationAlgorithm`]) for the matrix-free
//! [`SelfInteraction::evaluate_at`], which rotates the density per target with the rotation's
//! own `apply`. The dense self-interaction operator ([`SelfInteraction::assemble`], and its rows
//! over the density's coefficients, [`SelfInteraction::assemble_rows`]) is built in coefficient
//! space: a kernel row `K` of target `(i, k)` meets the density through the rotation
//! `Y_q L U_i Φ_k F`, so its row over the coefficients is `K Y_q L U_i Φ_k`, computed for all
//! `2p` targets of a latitude by one truncated forward transform (`Y_qᵀ = F_q W⁻¹`) and the
//! transposed rotation ([`ShRotation::adjoint_every_longitude`]): `O(p⁴ log p)` per latitude.
//! MOBO's way (Veerapaneni et al. 2011), one rotation matrix `B_i` per latitude (`n_q × n_p`;
//! [`DirectRotation`]'s `M_i`, or the same matrix built through [`ShRotation`]) and one GEMM
//! `(9·2p × n_q) · (n_q × n_p)`, `O(p⁵)`, is kept as
//! [`SelfInteraction::assemble_by_rotation_matrices`], the reference the tests hold the faster
//! assembly to (1e-12 relative; 1e-13 measured), beside the matrix-free evaluation. Without
//! upsampling (`q = p`) `assemble` is that reference method.
//!
//! Targets whose own far side comes close (the dimples of a red blood cell) split the integral
//! with a partition of unity on the parameter sphere ([`super::far_side`]): the Graham–Sloan rule
//! takes the windowed local part and a smooth rule of a higher order `Q` on the unrotated grid
//! the rest (on an RBC at `p = 16`: `q = 32` 9.8e-6 → 2.8e-7). Every path includes it; the
//! rows of the far part are folded in after the latitude loop (in coefficient space for
//! [`SelfInteraction::assemble`])
//! ([`SelfInteraction::set_far_side_params`] turns it off or tunes it).

mod kernel_columns;

use kernel_columns::{kernel_rows, kernel_rows_by_entry};

use super::layer_kernel::kernel_entries;
pub use super::layer_kernel::LayerKernel;
use std::f64::consts::PI;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::coefficient_operator::forward_matrix;
use super::far_side::{FarSide, FarSideParams};
use super::{check_len, cross, dot, get3, VesicleError};
use crate::sph_harmonics::{
    CoefLayout, Deriv, DirectRotation, GrahamSloan, Grid, ShRotation, ShTransform, ShWorkspace,
};

/// Which rotation carries a target to the north pole.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RotationAlgorithm {
    /// One dense `n_q × n_p` matrix per latitude (MOBO's choice; `O(p⁴)` memory per latitude).
    Direct,
    /// Per-degree Wigner-type blocks in coefficient space, then an inverse transform.
    ViaSh,
}

enum Rotator {
    Direct(DirectRotation),
    ViaSh(Box<ShRotation>),
}

/// On-surface layer potentials of one cell surface of order `p`, quadrature at order `q`.
pub struct SelfInteraction {
    p: usize,
    q: usize,
    rot: Rotator,
    sht_p: ShTransform,
    ws_p: ShWorkspace,
    sht_q: ShTransform,
    ws_q: ShWorkspace,
    /// Graham–Sloan weight per latitude of the order-`q` grid.
    gs: Vec<f64>,
    /// The same times the far-side window `η` (for flagged targets).
    gs_local: Vec<f64>,
    /// `gs` and `gs_local` divided by the order-`q` grid's quadrature weight of the latitude:
    /// kernel rows so weighted turn the forward transform into the adjoint of synthesis.
    gs_adjoint: Vec<f64>,
    gs_local_adjoint: Vec<f64>,
    /// The coefficient-space rotation for [`Self::assemble`] when `rot` is [`Rotator::Direct`]
    /// (built at the first assembly).
    sh_rot: Option<Box<ShRotation>>,
    far: FarSide,
    sin_q: Vec<f64>,
    // Scratch.
    x_grid: Vec<f64>,
    x_coef: Vec<f64>,
    /// Whether `x_coef`, `x_grid` and the far-side plan are those of a surface set.
    surface_set: bool,
    dens_coef: Vec<f64>,
    rot_vals: Vec<f64>,
    rot_coef: Vec<f64>,
    y: Vec<f64>,
    yt: Vec<f64>,
    yp: Vec<f64>,
    dens_rot: Vec<f64>,
    /// Kernel rows of one target, `9 × n_q` (row `3a + b`, column-major).
    kern: Vec<f64>,
    /// Per-latitude batches (allocated at the first assembly or batched application).
    scratch: Option<Box<LatitudeScratch>>,
    /// Scratch of [`Self::assemble`]'s coefficient-space rows (allocated at the first assembly).
    adjoint: Option<Box<AdjointScratch>>,
}

impl SelfInteraction {
    /// Layer potentials for surfaces of order `p`, quadrature order `q ≥ p`.
    pub fn new(p: usize, q: usize, algorithm: RotationAlgorithm) -> Result<Self, VesicleError> {
        if q < p {
            return Err(VesicleError::Order { p, q });
        }
        let rot = match algorithm {
            RotationAlgorithm::Direct => Rotator::Direct(DirectRotation::new(p, q)?),
            RotationAlgorithm::ViaSh => Rotator::ViaSh(Box::new(ShRotation::new(p, q)?)),
        };
        let sht_p = ShTransform::new(p)?;
        let sht_q = ShTransform::new(q)?;
        let (np, nq) = (sht_p.n_points(), sht_q.n_points());
        let (ncp, ncq) = (sht_p.n_coefs(), sht_q.n_coefs());
        let gs = GrahamSloan::new(q).latitude_weights;
        let far = FarSide::new(p, q)?;
        let gs_local: Vec<f64> = gs.iter().zip(&far.eta_q).map(|(w, e)| w * e).collect();
        let grid_q = Grid::new(q);
        let w_q: Vec<f64> = (0..=q)
            .map(|i| grid_q.gl_weights[i] * PI / q as f64)
            .collect();
        let gs_adjoint = gs.iter().zip(&w_q).map(|(a, w)| a / w).collect();
        let gs_local_adjoint = gs_local.iter().zip(&w_q).map(|(a, w)| a / w).collect();
        Ok(SelfInteraction {
            p,
            q,
            rot,
            ws_p: sht_p.workspace(),
            ws_q: sht_q.workspace(),
            gs,
            gs_local,
            gs_adjoint,
            gs_local_adjoint,
            sh_rot: None,
            far,
            sin_q: grid_q.sin_theta,
            x_grid: vec![0.0; 3 * np],
            x_coef: vec![0.0; 3 * ncp],
            surface_set: false,
            dens_coef: vec![0.0; 3 * ncp],
            rot_vals: vec![0.0; 3 * nq],
            rot_coef: vec![0.0; 3 * ncq],
            y: vec![0.0; 3 * nq],
            yt: vec![0.0; 3 * nq],
            yp: vec![0.0; 3 * nq],
            dens_rot: vec![0.0; 3 * nq],
            kern: vec![0.0; 9 * nq],
            scratch: None,
            adjoint: None,
            sht_p,
            sht_q,
        })
    }

    /// Surface order `p`.
    pub fn order(&self) -> usize {
        self.p
    }
    /// Quadrature order `q`.
    pub fn quadrature_order(&self) -> usize {
        self.q
    }
    /// The rotation that carries a target to the north pole.
    pub fn rotation_algorithm(&self) -> RotationAlgorithm {
        match self.rot {
            Rotator::Direct(_) => RotationAlgorithm::Direct,
            Rotator::ViaSh(_) => RotationAlgorithm::ViaSh,
        }
    }
    /// Grid points at order `p`.
    pub fn n_points(&self) -> usize {
        self.sht_p.n_points()
    }

    /// Settings of the split off of the cell's own far side ([`super::far_side`]).
    pub fn far_side_params(&self) -> FarSideParams {
        self.far.params()
    }

    /// Change the settings of the far-side split (see [`super::far_side`]).
    pub fn set_far_side_params(&mut self, params: FarSideParams) -> Result<(), VesicleError> {
        if params != self.far.params() {
            // The far-side plan of the surface set so far is stale.
            self.surface_set = false;
        }
        self.far.set_params(params)
    }

    /// For the surface of the last evaluation or assembly: the targets whose far side was split
    /// off (latitude-major indices) and the order `Q` of its grid (0 when there are none).
    pub fn far_side_plan(&self) -> (&[usize], usize) {
        self.far.plan()
    }

    /// Set the surface (grid values and far-side plan); kept when it is the surface already set
    /// (the products of a GMRES solve, or `S` and `D` at one geometry, share it).
    fn set_surface(&mut self, coefs: &[f64]) -> Result<(), VesicleError> {
        check_len("surface coefficients", coefs.len(), self.x_coef.len())?;
        if self.surface_set && self.x_coef == coefs {
            return Ok(());
        }
        self.surface_set = false;
        self.x_coef.copy_from_slice(coefs);
        self.sht_p
            .inverse(coefs, &mut self.x_grid, &mut self.ws_p)?;
        self.far.set_surface(&self.x_coef, &self.x_grid)?;
        self.surface_set = true;
        Ok(())
    }

    /// `y, y_θ, y_φ` of the surface rotated so that `(lat, lon)` is at the pole, from rotated
    /// coefficients in `rot_coef`.
    fn rotated_derivatives(&mut self) -> Result<(), VesicleError> {
        self.sht_q.synthesize(
            &self.rot_coef,
            &[Deriv::Value, Deriv::Theta, Deriv::Phi],
            &mut [&mut self.y, &mut self.yt, &mut self.yp],
            &mut self.ws_q,
        )?;
        Ok(())
    }

    /// Matrix-free evaluation at the listed targets (latitude-major indices of the order-`p`
    /// grid): `out` (component-major, `3 · targets.len()`) receives the layer potential of the
    /// density (component-major on the order-`p` grid) over the surface with coefficients
    /// `coefs`. The density is rotated per target with the rotation's own `apply`.
    pub fn evaluate_at(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        density: &[f64],
        targets: &[usize],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        kernel.check()?;
        let np = self.n_points();
        check_len("density", density.len(), 3 * np)?;
        check_len("output", out.len(), 3 * targets.len())?;
        if let Some(&t) = targets.iter().find(|&&t| t >= np) {
            return Err(VesicleError::Length {
                what: "target index (beyond the grid)",
                len: t,
                expected: np,
            });
        }
        self.set_surface(coefs)?;
        self.far.set_density(density)?;
        if matches!(self.rot, Rotator::ViaSh(_)) {
            self.sht_p
                .forward(density, &mut self.dens_coef, &mut self.ws_p)?;
        }
        let nq = self.sht_q.n_points();
        let nlon = 2 * self.p;
        let nt = targets.len();
        for (ti, &t) in targets.iter().enumerate() {
            let (lat, lon) = (t / nlon, t % nlon);
            match &mut self.rot {
                Rotator::Direct(d) => {
                    d.apply(lat, lon, &self.x_grid, &mut self.rot_vals)?;
                    self.sht_q
                        .forward(&self.rot_vals, &mut self.rot_coef, &mut self.ws_q)?;
                    d.apply(lat, lon, density, &mut self.dens_rot)?;
                }
                Rotator::ViaSh(r) => {
                    r.rotate_coefs(lat, lon, &self.x_coef, &mut self.rot_coef)?;
                    r.apply(lat, lon, &self.dens_coef, &mut self.dens_rot)?;
                }
            }
            self.rotated_derivatives()?;
            let xt = get3(&self.x_grid, np, t);
            let flagged = self.far.flagged[t];
            kernel_rows(
                kernel,
                xt,
                &self.y,
                &self.yt,
                &self.yp,
                if flagged { &self.gs_local } else { &self.gs },
                &self.sin_q,
                &mut self.kern,
            );
            let mut u = [0.0; 3];
            for j in 0..nq {
                let f = get3(&self.dens_rot, nq, j);
                let col = &self.kern[9 * j..9 * j + 9];
                for (a, ua) in u.iter_mut().enumerate() {
                    *ua += col[3 * a] * f[0] + col[3 * a + 1] * f[1] + col[3 * a + 2] * f[2];
                }
            }
            if flagged {
                self.far.add_far(kernel, t, xt, &mut u);
            }
            for (a, ua) in u.iter().enumerate() {
                out[a * nt + ti] = *ua;
            }
        }
        Ok(())
    }

    /// Matrix-free evaluation at every grid point (`out`: component-major, `3 n_p`).
    pub fn evaluate(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        density: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let targets: Vec<usize> = (0..self.n_points()).collect();
        self.evaluate_at(kernel, coefs, density, &targets, out)
    }

    /// The dense self-interaction operator `A` (`3n_p × 3n_p`, column-major, rows and columns
    /// component-major) with `A · density = evaluate(density)` for every density on the grid.
    ///
    /// The rows are built in coefficient space. For target `(i, k)` the rotated density on the
    /// order-`q` grid is `Y_q L U_i Φ_k F f` (`F` the forward transform at order `p`, `Φ_k` the
    /// phase shift of longitude `k`, `U_i` the degree blocks of latitude `i`, `L` the copy into
    /// the order-`q` layout, `Y_q` synthesis at order `q`; [`ShRotation`]), so a kernel row `K`
    /// (`1 × n_q`) meets the density as `ρ F f` with `ρ = K Y_q L U_i Φ_k`. Per latitude, the
    /// `6·2p` distinct rows `K` (the kernels are symmetric) go through `Y_qᵀ` (a forward
    /// transform of `K / w`, truncated to the degrees `≤ p + 1`; `w` the grid's
    /// quadrature weights: `F_q = Y_qᵀ W`) and the transposed rotation
    /// ([`ShRotation::adjoint_every_longitude`]); the far side of flagged targets adds its rows
    /// in the same coefficient space ([`super::far_side`]); the rows `ρ` of all targets are
    /// then multiplied by `F`, one GEMM per source component. That is `O(p⁴ log p)` work per
    /// latitude where [`Self::assemble_by_rotation_matrices`] spends the `O(p⁵)` GEMM
    /// `K · B_i`; both give the same operator to round-off. Needs `q > p` (else it is that
    /// method).
    pub fn assemble(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        if self.q == self.p {
            // F_q = Y_qᵀ W fails for the Nyquist order m = q; nothing to gain without upsampling.
            return self.assemble_by_rotation_matrices(kernel, coefs, out);
        }
        let n3 = 3 * self.n_points();
        check_len("operator", out.len(), n3 * n3)?;
        let out = MatMut::from_column_major_slice_mut(out, n3, n3);
        self.assemble_latitudes(kernel, coefs, 0..self.p + 1, out)
    }

    /// The rows of [`Self::assemble`] for the targets on the grid's latitudes `lats` only (a
    /// band of the surface, `k = 2p·|lats|` targets from `t₀ = 2p·lats.start`): `out` is
    /// `3k × 3n_p` (any strides: a block of a larger matrix), row `a·k + (t − t₀)`, column
    /// `b·n_p + j`. The rows are
    /// those of the whole operator, computed latitude by latitude as it is; a wall split over
    /// MPI ranks assembles each rank's band this way ([`crate::wall`]).
    ///
    /// # Errors
    /// [`VesicleError::Parameter`] for latitudes past the grid's `p + 1`; as
    /// [`Self::assemble`] otherwise.
    pub fn assemble_latitudes(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        lats: std::ops::Range<usize>,
        mut out: MatMut<'_, f64>,
    ) -> Result<(), VesicleError> {
        if lats.start > lats.end || lats.end > self.p + 1 {
            return Err(VesicleError::Parameter {
                name: "last latitude",
                value: lats.end as f64 - 1.0,
                reason: "the latitudes must form a range within the grid's 0..=p",
            });
        }
        let np = self.n_points();
        let nlon = 2 * self.p;
        let (k, t0) = (nlon * lats.len(), nlon * lats.start);
        let k3 = 3 * k;
        if (out.nrows(), out.ncols()) != (k3, 3 * np) {
            return Err(VesicleError::Length {
                what: "operator rows (rows × columns)",
                len: out.nrows() * out.ncols(),
                expected: k3 * 3 * np,
            });
        }
        if self.q == self.p {
            let n3 = 3 * np;
            let mut whole = vec![0.0; n3 * n3];
            self.assemble_by_rotation_matrices(kernel, coefs, &mut whole)?;
            for col in 0..n3 {
                for a in 0..3 {
                    for t in 0..k {
                        out[(a * k + t, col)] = whole[col * n3 + a * np + t0 + t];
                    }
                }
            }
            return Ok(());
        }
        let lp = self.sht_p.n_coefs();
        let mut rows = self
            .adjoint
            .as_mut()
            .map(|ad| std::mem::take(&mut ad.rows))
            .unwrap_or_default();
        rows.resize(k3 * 3 * lp, 0.0);
        let r = self.band_rows(kernel, coefs, lats, &mut rows);
        if r.is_ok() {
            let forward = &self.adjoint.as_ref().expect("built by the rows").forward;
            let rows = MatRef::from_row_major_slice(&rows, k3, 3 * lp);
            for b in 0..3 {
                matmul(
                    out.as_mut().submatrix_mut(0, b * np, k3, np),
                    Accum::Replace,
                    rows.submatrix(0, b * lp, k3, lp),
                    MatRef::from_column_major_slice(forward, lp, np),
                    1.0,
                    Par::Seq,
                );
            }
        }
        if let Some(ad) = self.adjoint.as_mut() {
            ad.rows = rows;
        }
        r
    }

    /// The operator of [`Self::assemble`] before its last product: the rows `P` over the
    /// density's coefficients (`3n_p × 3n_c`, **row-major**, row `a·n_p + t`, column
    /// `b·n_c + k` for coefficient `k` of density component `b`), so that
    /// `A = P · blockdiag(F, F, F)` and `A f = P (F f)`: half the entries of `A` at `p = 12`,
    /// applied after a forward transform of the density. Needs `q > p`
    /// ([`VesicleError::NotUpsampled`] otherwise).
    pub fn assemble_rows(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        self.band_rows(kernel, coefs, 0..self.p + 1, out)
    }

    /// [`Self::assemble_rows`] for the targets on the latitudes `lats` (`k` of them, row
    /// `a·k + (t − t₀)` as in [`Self::assemble_latitudes`]).
    fn band_rows(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        lats: std::ops::Range<usize>,
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        if self.q == self.p {
            return Err(VesicleError::NotUpsampled { p: self.p });
        }
        kernel.check()?;
        let nlon = 2 * self.p;
        let lp = self.sht_p.n_coefs();
        let held = nlon * lats.start..nlon * lats.end;
        check_len("operator rows", out.len(), 9 * held.len() * lp)?;
        self.set_surface(coefs)?;
        if matches!(self.rot, Rotator::Direct(_)) && self.sh_rot.is_none() {
            self.sh_rot = Some(Box::new(ShRotation::new(self.p, self.q)?));
        }
        let mut sc = self.latitude_scratch()?;
        let mut ad = match self.adjoint.take() {
            Some(ad) => ad,
            None => Box::new(AdjointScratch::new(
                &self.sht_p,
                &mut self.ws_p,
                &self.sht_q,
                2 * self.p,
            )?),
        };
        let r = self
            .coefficient_rows(kernel, &mut sc, &mut ad, lats, out)
            .and_then(|()| {
                self.far
                    .add_coefficient_rows(kernel, &self.x_grid, held, out)
            });
        self.scratch = Some(sc);
        self.adjoint = Some(ad);
        r
    }

    /// The rows `ρ` of [`Self::assemble_rows`] for the targets on the latitudes `lats` into
    /// `rows` (row `a·k + (t − t₀)`, [`Self::assemble_latitudes`]).
    fn coefficient_rows(
        &mut self,
        kernel: LayerKernel,
        sc: &mut LatitudeScratch,
        ad: &mut AdjointScratch,
        lats: std::ops::Range<usize>,
        rows: &mut [f64],
    ) -> Result<(), VesicleError> {
        let (np, nq, lp) = (
            self.sht_p.n_points(),
            self.sht_q.n_points(),
            self.sht_p.n_coefs(),
        );
        let nlon = 2 * self.p;
        let rot: &mut ShRotation = match &mut self.rot {
            Rotator::ViaSh(r) => r,
            Rotator::Direct(_) => self.sh_rot.as_mut().expect("built before the rows are"),
        };
        let lw = ad.wide.len();
        let c_rot = &mut sc.c_all[..3 * nlon * lw];
        let (k, t0) = (nlon * lats.len(), nlon * lats.start);
        for lat in lats {
            // The rotated surfaces of the latitude's 2p targets and their derivatives (degrees
            // ≤ p, in the layout of order p + 1, on the order-q grid).
            rot.rotate_coefs_every_longitude(lat, &self.x_coef, c_rot)?;
            self.sht_q.synthesize_from(
                &ad.wide,
                c_rot,
                &[Deriv::Value, Deriv::Theta, Deriv::Phi],
                &mut [&mut sc.y_all, &mut sc.yt_all, &mut sc.yp_all],
                &mut self.ws_q,
            )?;
            // Kernel rows, one function per symmetric entry (6k + e), divided by the grid
            // weights.
            for lon in 0..nlon {
                let t = lat * nlon + lon;
                let blk = lon * 3 * nq..(lon + 1) * 3 * nq;
                kernel_rows_by_entry(
                    kernel,
                    get3(&self.x_grid, np, t),
                    &sc.y_all[blk.clone()],
                    &sc.yt_all[blk.clone()],
                    &sc.yp_all[blk],
                    if self.far.flagged[t] {
                        &self.gs_local_adjoint
                    } else {
                        &self.gs_adjoint
                    },
                    &self.sin_q,
                    &mut sc.kmat[6 * lon * nq..6 * (lon + 1) * nq],
                );
            }
            // ρ = K Y_q L U_i Φ_k for all of them (Y_qᵀ only for the degrees ≤ p + 1).
            let nk = 6 * nlon * nq;
            self.sht_q
                .forward_to(&ad.wide, &sc.kmat[..nk], &mut ad.kcoef, &mut self.ws_q)?;
            rot.adjoint_every_longitude(lat, 6, &ad.kcoef, &mut ad.rho)?;
            for lon in 0..nlon {
                let t = lat * nlon + lon;
                for (e, &(a, b)) in SYM.iter().enumerate() {
                    let g = 6 * lon + e;
                    let rho = &ad.rho[g * lp..(g + 1) * lp];
                    let tl = t - t0;
                    let (ra, rb) = ((a * k + tl) * 3 * lp, (b * k + tl) * 3 * lp);
                    rows[ra + b * lp..ra + (b + 1) * lp].copy_from_slice(rho);
                    if a != b {
                        rows[rb + a * lp..rb + (a + 1) * lp].copy_from_slice(rho);
                    }
                }
            }
        }
        Ok(())
    }

    /// The same operator as [`Self::assemble`], by the rotation matrices `B_i` (`n_q × n_p`;
    /// [`DirectRotation`]'s `M_i`, or the same matrix built through [`ShRotation`]): one GEMM
    /// `(9·2p × n_q) · (n_q × n_p)` per latitude for the kernel rows of all `2p` targets, the
    /// longitude shift applied when the rows are scattered. MOBO's way (Veerapaneni et al.
    /// 2011); kept as the reference the faster assembly is checked against.
    pub fn assemble_by_rotation_matrices(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        kernel.check()?;
        let np = self.n_points();
        let n3 = 3 * np;
        check_len("operator", out.len(), n3 * n3)?;
        self.set_surface(coefs)?;
        let nq = self.sht_q.n_points();
        let nlon = 2 * self.p;
        let rows = 9 * nlon;
        let mut sc = self.latitude_scratch()?;
        for lat in 0..=self.p {
            self.latitude_rows(kernel, lat, &mut sc)?;
            let b = rotation_matrix(&self.rot, &sc.b_sh, lat);
            matmul(
                MatMut::from_column_major_slice_mut(&mut sc.cmat, rows, np),
                Accum::Replace,
                MatRef::from_column_major_slice(&sc.kmat, rows, nq),
                MatRef::from_column_major_slice(b, nq, np),
                1.0,
                Par::Seq,
            );
            // Scatter: the density at c = (lat(c'), lon(c') + k) meets column c' of B_i.
            for lon in 0..nlon {
                let t = lat * nlon + lon;
                for cp in 0..np {
                    let (cl, ck) = (cp / nlon, cp % nlon);
                    let c = cl * nlon + (ck + lon) % nlon;
                    let src = &sc.cmat[cp * rows + 9 * lon..cp * rows + 9 * lon + 9];
                    for a in 0..3 {
                        for bb in 0..3 {
                            out[(bb * np + c) * n3 + a * np + t] = src[3 * a + bb];
                        }
                    }
                }
            }
        }
        self.scratch = Some(sc);
        self.far.add_rows(kernel, &self.x_grid, out)?;
        Ok(())
    }

    /// Matrix-free application at every grid point, batched per latitude like
    /// [`Self::assemble_by_rotation_matrices`] (memory linear in the points per cell, time per
    /// call about half such an assembly): `out = A · density` (component-major, `3n_p` each),
    /// the same numbers as the dense operator's product to round-off.
    ///
    /// Per latitude `i`: the rotated surfaces of its `2p` targets and their kernel rows `K`
    /// (as in that assembly), the rotated densities `B_i S_k f` of all targets in one GEMM, and
    /// per target the contraction `Σ_j K(j) (B_i S_k f)(j)`; flagged targets add their far
    /// side ([`super::far_side`]).
    pub fn apply(
        &mut self,
        kernel: LayerKernel,
        coefs: &[f64],
        density: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        kernel.check()?;
        let np = self.n_points();
        check_len("density", density.len(), 3 * np)?;
        check_len("output", out.len(), 3 * np)?;
        self.set_surface(coefs)?;
        self.far.set_density(density)?;
        let nq = self.sht_q.n_points();
        let nlon = 2 * self.p;
        let rows = 9 * nlon;
        let mut sc = self.latitude_scratch()?;
        // The density shifted by every longitude (np × 3·2p), as the surface.
        shift_every_longitude(self.p, density, &mut sc.ds);
        for lat in 0..=self.p {
            self.latitude_rows(kernel, lat, &mut sc)?;
            // Rotated densities of all 2p targets (n_q × 3·2p), reusing the values' scratch.
            let b = rotation_matrix(&self.rot, &sc.b_sh, lat);
            rotate_batch(b, np, &sc.ds, &mut sc.y_all);
            for lon in 0..nlon {
                let t = lat * nlon + lon;
                let d = &sc.y_all[lon * 3 * nq..(lon + 1) * 3 * nq];
                let mut u = [0.0; 3];
                for j in 0..nq {
                    let k = &sc.kmat[j * rows + 9 * lon..j * rows + 9 * lon + 9];
                    let f = [d[j], d[nq + j], d[2 * nq + j]];
                    for (a, ua) in u.iter_mut().enumerate() {
                        *ua += k[3 * a] * f[0] + k[3 * a + 1] * f[1] + k[3 * a + 2] * f[2];
                    }
                }
                if self.far.flagged[t] {
                    self.far
                        .add_far(kernel, t, get3(&self.x_grid, np, t), &mut u);
                }
                for (a, ua) in u.iter().enumerate() {
                    out[a * np + t] = *ua;
                }
            }
        }
        self.scratch = Some(sc);
        Ok(())
    }

    /// The per-latitude scratch (kept between calls), with the surface of the last
    /// `set_surface` shifted by every longitude.
    fn latitude_scratch(&mut self) -> Result<Box<LatitudeScratch>, VesicleError> {
        let (np, nq, ncq) = (
            self.sht_p.n_points(),
            self.sht_q.n_points(),
            self.sht_q.n_coefs(),
        );
        let nlon = 2 * self.p;
        let nf = 3 * nlon;
        let mut sc = match self.scratch.take() {
            Some(sc) => sc,
            None => {
                let b_sh = match self.rot {
                    Rotator::ViaSh(_) => Some((
                        forward_matrix(&self.sht_p, &mut self.ws_p)?,
                        vec![0.0; nq * np],
                    )),
                    Rotator::Direct(_) => None,
                };
                Box::new(LatitudeScratch {
                    xs: vec![0.0; np * nf],
                    ds: vec![0.0; np * nf],
                    y_all: vec![0.0; nq * nf],
                    yt_all: vec![0.0; nq * nf],
                    yp_all: vec![0.0; nq * nf],
                    c_all: vec![0.0; ncq * nf],
                    kmat: vec![0.0; 9 * nlon * nq],
                    cmat: vec![0.0; 9 * nlon * np],
                    b_sh,
                })
            }
        };
        shift_every_longitude(self.p, &self.x_grid, &mut sc.xs);
        Ok(sc)
    }

    /// For latitude `lat`: `B_i` (ViaSh), the rotated surfaces `Y_k = B_i S_k X` of its `2p`
    /// targets with their derivatives (one GEMM, batched transforms at order `q`) and their
    /// stacked kernel rows `sc.kmat` (`9·2p × n_q`, row `9k + 3a + b`).
    fn latitude_rows(
        &mut self,
        kernel: LayerKernel,
        lat: usize,
        sc: &mut LatitudeScratch,
    ) -> Result<(), VesicleError> {
        let (np, nq) = (self.sht_p.n_points(), self.sht_q.n_points());
        let nlon = 2 * self.p;
        let rows = 9 * nlon;
        if let (Rotator::ViaSh(r), Some((f, b))) = (&mut self.rot, sc.b_sh.as_mut()) {
            r.apply(lat, 0, f, b)?;
        }
        let b = rotation_matrix(&self.rot, &sc.b_sh, lat);
        rotate_batch(b, np, &sc.xs, &mut sc.y_all);
        self.sht_q
            .forward(&sc.y_all, &mut sc.c_all, &mut self.ws_q)?;
        self.sht_q.synthesize(
            &sc.c_all,
            &[Deriv::Value, Deriv::Theta, Deriv::Phi],
            &mut [&mut sc.y_all, &mut sc.yt_all, &mut sc.yp_all],
            &mut self.ws_q,
        )?;
        for lon in 0..nlon {
            let t = lat * nlon + lon;
            let blk = lon * 3 * nq..(lon + 1) * 3 * nq;
            kernel_rows(
                kernel,
                get3(&self.x_grid, np, t),
                &sc.y_all[blk.clone()],
                &sc.yt_all[blk.clone()],
                &sc.yp_all[blk],
                if self.far.flagged[t] {
                    &self.gs_local
                } else {
                    &self.gs
                },
                &self.sin_q,
                &mut self.kern,
            );
            for j in 0..nq {
                sc.kmat[j * rows + 9 * lon..j * rows + 9 * lon + 9]
                    .copy_from_slice(&self.kern[9 * j..9 * j + 9]);
            }
        }
        Ok(())
    }
}

/// `src` (component-major vector field on the order-`p` grid, `3n_p`) shifted by every
/// longitude `k = 0 … 2p−1` into `dst` (`n_p × 3·2p`, shift `k` in columns `3k … 3k+2`).
fn shift_every_longitude(p: usize, src: &[f64], dst: &mut [f64]) {
    for (lon, d) in dst.chunks_exact_mut(src.len()).enumerate() {
        crate::sph_harmonics::rotation::shift_longitudes(p, lon, src, d);
    }
}

/// `out = B · src` for a rotation matrix `B` (`n_q × n_p`) and a batch of functions `src`
/// (`n_p × k`) into `out` (`n_q × k`).
fn rotate_batch(b: &[f64], np: usize, src: &[f64], out: &mut [f64]) {
    let (nq, k) = (b.len() / np, src.len() / np);
    matmul(
        MatMut::from_column_major_slice_mut(out, nq, k),
        Accum::Replace,
        MatRef::from_column_major_slice(b, nq, np),
        MatRef::from_column_major_slice(src, np, k),
        1.0,
        Par::Seq,
    );
}

/// `B_i` of latitude `lat` (for `ViaSh`: as built by the last
/// [`SelfInteraction::latitude_rows`] into `b_sh`).
fn rotation_matrix<'a>(
    rot: &'a Rotator,
    b_sh: &'a Option<(Vec<f64>, Vec<f64>)>,
    lat: usize,
) -> &'a [f64] {
    match (rot, b_sh.as_ref()) {
        (Rotator::Direct(d), _) => d.matrix(lat).expect("all latitudes are built"),
        (Rotator::ViaSh(_), Some((_, b))) => b,
        _ => unreachable!("ViaSh always has its B_i scratch"),
    }
}

/// Scratch of the per-latitude batches of [`SelfInteraction::assemble`] and
/// [`SelfInteraction::apply`] (`2p` targets at a time).
struct LatitudeScratch {
    /// The surface and the density shifted by every longitude (`n_p × 3·2p`).
    xs: Vec<f64>,
    ds: Vec<f64>,
    /// Rotated surfaces (then rotated densities), their derivatives (`n_q × 3·2p`) and
    /// coefficients.
    y_all: Vec<f64>,
    yt_all: Vec<f64>,
    yp_all: Vec<f64>,
    c_all: Vec<f64>,
    /// Stacked kernel rows (`9·2p × n_q`) and their product with `B_i` (`9·2p × n_p`).
    kmat: Vec<f64>,
    cmat: Vec<f64>,
    /// ViaSh: the forward matrix `F` and `B_i`.
    b_sh: Option<(Vec<f64>, Vec<f64>)>,
}

/// The entries `(a, b)`, `a ≤ b`, of the symmetric kernels.
const SYM: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

/// Scratch of [`SelfInteraction::assemble`] (rows in coefficient space).
struct AdjointScratch {
    /// The forward transform at order `p` as a matrix (`n_c(p) × n_p`, column-major).
    forward: Vec<f64>,
    /// The layout of order `p + 1` ([`ShRotation::wide_layout`]).
    wide: CoefLayout,
    /// Coefficients (layout `wide`) of one latitude's kernel rows (`6·2p` functions: the
    /// symmetric entries).
    kcoef: Vec<f64>,
    /// Their rows `ρ` (order-`p` layout, `6·2p` functions).
    rho: Vec<f64>,
    /// The rows of [`SelfInteraction::assemble`] (as [`SelfInteraction::assemble_rows`] lays
    /// them out; moved out while they are filled).
    rows: Vec<f64>,
}

impl AdjointScratch {
    fn new(
        sht_p: &ShTransform,
        ws_p: &mut ShWorkspace,
        sht_q: &ShTransform,
        nlon: usize,
    ) -> Result<Self, VesicleError> {
        let wide = CoefLayout::new(sht_p.order() + 1);
        let (lp, lw) = (sht_p.n_coefs(), wide.len());
        debug_assert!(wide.order() <= sht_q.order());
        Ok(AdjointScratch {
            forward: forward_matrix(sht_p, ws_p)?,
            wide,
            kcoef: vec![0.0; 6 * nlon * lw],
            rho: vec![0.0; 6 * nlon * lp],
            // Filled by `assemble` only (`assemble_rows` writes the caller's buffer).
            rows: Vec::new(),
        })
    }
}
