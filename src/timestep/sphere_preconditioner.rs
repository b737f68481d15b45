//! The preconditioner from the sphere: the exact inverse of the semi-implicit step operator of the
//! sphere of the cell's area-equivalent radius (Veerapaneni, Rahimian, Biros & Zorin, J. Comput.
//! Phys. 230 (2011) 5610, §3.5: "a spectral block-diagonal preconditioner from the sphere").
//!
//! ## The operator
//!
//! The step system of [`super::semi_implicit`] for the unknowns `z = [X; σ]` (grid values, `3n`
//! positions component-major and `n` tensions, `n = 2p(p+1)`) is
//!
//! ```text
//!     A z = [ a X − c_D D X − τ S (B X + T σ) ;  Div X ]
//! ```
//!
//! with `a = (1+λ)/2`, `c_D = 1 − λ`, `τ = Δt` (Euler) or `2Δt/3` (BDF2), and `S, D, B, T, Div`
//! the single layer, double layer, linearised bending, tension and surface divergence frozen at
//! the (extrapolated) geometry. Every one of them is invariant under translations and
//! equivariant under rotations of the surface, so on a sphere of radius `R` the operator `A_R`
//! commutes with rotations and is diagonal in degree in a vector-spherical-harmonic basis
//! (radial, poloidal, toroidal and tension components of degree `l` couple in a `4 × 4` block,
//! the same for every order `m`). Its inverse is the preconditioner `M⁻¹ = A_R⁻¹`, applied on the
//! **right** of GMRES (so the stopping test is on the true residual).
//!
//! ## What is built (the dense first version)
//!
//! The operator is built numerically in SH-coefficient space, from the same discrete `S, D, B,
//! T, Div` as the step (so its inverse is exact for the discrete sphere, to rounding): with `F`
//! the forward transform (grid → the `n_c = (p+1)² − 1` coefficients of each of the 4 fields) and
//! `F⁻¹` the synthesis, `C = A_R F⁻¹` (`4n × 4n_c`, one operator application per coefficient,
//! the `S`/`D` products as one GEMM each) and the coefficient block `A_bb = F C`
//! (`4n_c × 4n_c`). The grid space is larger than the coefficient space (`n > n_c`); on its
//! complement `ker F` the discrete operator is `a I` on positions (`B`, `Div`, `D` see only
//! `F X`) and zero on tensions (`T` sees only `F σ`), and the `X` rows of `C` have a component
//! `C_c = (I − F⁻¹F) C` there (the single layer of a degree-`p` density has degree-`p+1`
//! content). In the splitting grid = band-limited ⊕ complement the operator is block lower
//! triangular, `[[A_bb, 0], [C_c, a I]]`, and its inverse is applied as
//!
//! ```text
//!     c = F v,   y = A_bb⁻¹ c,   z = F⁻¹ y + [ (v − F⁻¹F v − G c)/a ; v_σ − F⁻¹F v_σ ],
//!     G = C_c A_bb⁻¹  (precomputed, 3n × 4n_c).
//! ```
//!
//! The constant tension does nothing on a sphere (`T 1 = 2H n = −(2/R) n` and `S[n] = 0` on
//! every closed surface), so `A_bb` is singular in that one column; the preconditioner uses
//! `A_bb + e e^T` (`e` the unit vector of the `σ₀₀` coefficient), which changes nothing else.
//! (The tension complement is passed through unchanged: those columns of `A` vanish.)
//!
//! Cost: the build applies the local operators `4n_c` times, two `(3n)² × 4n_c` GEMMs (`S`, and
//! `D` when `λ ≠ 1`), one LU of `4n_c` and its inverse: `≈ 4 (4n_c)³ + 2 (3n)² 4n_c` flops, once
//! per run (rebuilt only when `R`, `Δt`, `κ`, `μ` or `λ` change; the drift correction keeps the
//! area, hence `R`, fixed). Memory: `(4n_c)² + 3n · 4n_c` doubles (p = 12: 676² + 936·676 →
//! 8.7 MB; p = 16: 1156² + 1632·1156 → 26 MB). One application: five transforms of four fields
//! at order `p` and two GEMVs, `2(4n_c)² + 2·3n·4n_c` flops — comparable to one product with the
//! dense single layer (`2 (3n)²`), so the iteration count translates into time.
//!
//! The block structure (`4 × 4` per `(l, m)` in a rotation-adapted basis) would bring the
//! application to `O(p³)` with `O(p²)` memory; the dense coefficient-space inverse is the
//! documented first version.

use std::sync::Mutex;

use faer::linalg::matmul::matmul;
use faer::linalg::solvers::DenseSolveCore;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::{Preconditioner, TimestepError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::layer::{LayerKernel, SelfInteraction};
use crate::vesicle::membrane::Membrane;
use crate::vesicle::shapes;
use crate::vesicle::VesicleError;

/// The scalar coefficients of the step operator
/// `[X; σ] ↦ [a X − c_D D X − τ S (B X + T σ); Div X]` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepCoefficients {
    /// `a = (1 + λ)/2`.
    pub identity: f64,
    /// `c_D = 1 − λ` (0: no double layer).
    pub double_layer: f64,
    /// `τ`: `Δt` (Euler) or `2Δt/3` (BDF2).
    pub tau: f64,
    /// Bending modulus `κ_b`.
    pub bending_modulus: f64,
    /// Outer viscosity `μ` of the single layer.
    pub viscosity: f64,
}

impl StepCoefficients {
    /// For viscosity ratio `λ`, time factor `τ`, bending modulus `κ` and viscosity `μ`.
    pub fn new(viscosity_ratio: f64, tau: f64, bending_modulus: f64, viscosity: f64) -> Self {
        Self {
            identity: 0.5 * (1.0 + viscosity_ratio),
            double_layer: 1.0 - viscosity_ratio,
            tau,
            bending_modulus,
            viscosity,
        }
    }
}

struct Scratch {
    ws: ShWorkspace,
    /// `F v` (`4n_c`).
    c: Vec<f64>,
    /// `A_bb⁻¹ c` (`4n_c`).
    y: Vec<f64>,
    /// `F⁻¹ F v` (`4n`).
    pv: Vec<f64>,
    /// `G c` (`3n`).
    w: Vec<f64>,
}

/// The inverse step operator of a sphere (see the module docs), a right preconditioner of the
/// step of a cell of the same area.
pub struct SpherePreconditioner {
    p: usize,
    q: usize,
    radius: f64,
    coefs: StepCoefficients,
    sht: ShTransform,
    /// `(A_bb + e eᵀ)⁻¹`, `4n_c × 4n_c`.
    inv: Mat<f64>,
    /// `G = C_c A_bb⁻¹`, `3n × 4n_c`.
    g: Mat<f64>,
    scratch: Mutex<Scratch>,
}

impl SpherePreconditioner {
    /// Build the preconditioner for the sphere of radius `radius` with the operators of
    /// `membrane` (orders `p`, `q`) and `layer` (which are left holding the sphere's geometry).
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] for a non-positive radius or coefficients,
    /// [`TimestepError::Vesicle`] from the operators, [`TimestepError::SingularBlock`] if the
    /// sphere's operator is singular (it is not for `a > 0`, `τ > 0`).
    pub fn build(
        membrane: &mut Membrane,
        layer: &mut SelfInteraction,
        radius: f64,
        coefs: StepCoefficients,
    ) -> Result<Self, TimestepError> {
        for (name, v) in [
            ("radius", radius),
            ("identity coefficient", coefs.identity),
            ("tau", coefs.tau),
            ("bending_modulus", coefs.bending_modulus),
            ("viscosity", coefs.viscosity),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(TimestepError::InvalidParameter {
                    name,
                    value: format!("{v}"),
                    reason: "must be positive and finite",
                });
            }
        }
        if !coefs.double_layer.is_finite() {
            return Err(TimestepError::NonFinite {
                what: "double-layer coefficient",
            });
        }
        let p = membrane.order();
        let q = membrane.upsampled_order();
        if layer.order() != p {
            return Err(TimestepError::DimensionMismatch {
                what: "layer order",
                expected: p,
                got: layer.order(),
            });
        }
        let sht = ShTransform::new(p).map_err(VesicleError::from)?;
        let mut ws = sht.workspace();
        let (n, nc) = (sht.n_points(), sht.n_coefs());
        let (n3, m) = (3 * n, 4 * nc);
        let sphere = shapes::sphere(p, radius)?;
        membrane.set_geometry(sphere.coefs())?;
        // Inputs F⁻¹ e_j (4n × 4n_c) and the forces B X_j + T σ_j (3n × 4n_c), Div X_j.
        let mut cin = vec![0.0; 4 * nc];
        let mut inputs = vec![0.0; 4 * n * m];
        let mut forces = vec![0.0; n3 * m];
        let mut out = vec![0.0; 4 * n * m];
        let mut ft = vec![0.0; n3];
        for j in 0..m {
            cin.fill(0.0);
            cin[j] = 1.0;
            let col = &mut inputs[j * 4 * n..(j + 1) * 4 * n];
            sht.inverse(&cin, col, &mut ws)
                .map_err(VesicleError::from)?;
            let (x, sigma) = col.split_at(n3);
            let f = &mut forces[j * n3..(j + 1) * n3];
            membrane.bending_linear(coefs.bending_modulus, x, f)?;
            membrane.tension_force(sigma, &mut ft)?;
            for (a, b) in f.iter_mut().zip(&ft) {
                *a += b;
            }
            let o = &mut out[j * 4 * n..(j + 1) * 4 * n];
            membrane.surface_divergence(x, &mut o[n3..])?;
            for (oi, xi) in o[..n3].iter_mut().zip(x) {
                *oi = coefs.identity * xi;
            }
        }
        let mut op = vec![0.0; n3 * n3];
        // out[X rows of each column] += beta · op · rhs (rhs columns `stride` apart).
        let gemm = |op: &[f64], rhs: &[f64], stride: usize, out: &mut [f64], beta: f64| {
            matmul(
                MatMut::from_column_major_slice_with_stride_mut(out, n3, m, 4 * n),
                Accum::Add,
                MatRef::from_column_major_slice(op, n3, n3),
                MatRef::from_column_major_slice_with_stride(rhs, n3, m, stride),
                beta,
                Par::Seq,
            );
        };
        layer.assemble(
            LayerKernel::SingleLayer {
                viscosity: coefs.viscosity,
            },
            sphere.coefs(),
            &mut op,
        )?;
        gemm(&op, &forces, n3, &mut out, -coefs.tau);
        if coefs.double_layer != 0.0 {
            layer.assemble(LayerKernel::DoubleLayer, sphere.coefs(), &mut op)?;
            gemm(&op, &inputs, 4 * n, &mut out, -coefs.double_layer);
        }
        drop((op, forces, inputs));
        // A_bb = F C, C_c = (I − F⁻¹F) C on the X rows.
        let mut abb = Mat::<f64>::zeros(m, m);
        let mut cc = Mat::<f64>::zeros(n3, m);
        let mut coef = vec![0.0; 4 * nc];
        let mut proj = vec![0.0; 4 * n];
        for j in 0..m {
            let o = &out[j * 4 * n..(j + 1) * 4 * n];
            if !o.iter().all(|v| v.is_finite()) {
                return Err(TimestepError::NonFinite {
                    what: "sphere step operator",
                });
            }
            sht.forward(o, &mut coef, &mut ws)
                .map_err(VesicleError::from)?;
            sht.inverse(&coef, &mut proj, &mut ws)
                .map_err(VesicleError::from)?;
            for (i, c) in coef.iter().enumerate() {
                abb[(i, j)] = *c;
            }
            for i in 0..n3 {
                cc[(i, j)] = o[i] - proj[i];
            }
        }
        // The constant tension is a null direction on the sphere (see the module docs).
        let s00 = 3 * nc;
        abb[(s00, s00)] += 1.0;
        let lu = abb.partial_piv_lu();
        let (mut lo, mut hi) = (f64::INFINITY, 0.0_f64);
        let u = lu.U();
        for i in 0..m {
            lo = lo.min(u[(i, i)].abs());
            hi = hi.max(u[(i, i)].abs());
        }
        let pivot_ratio = if hi > 0.0 { lo / hi } else { 0.0 };
        if pivot_ratio <= m as f64 * f64::EPSILON {
            return Err(TimestepError::SingularBlock {
                index: 0,
                size: m,
                pivot_ratio,
            });
        }
        let inv = lu.inverse();
        let mut g = Mat::<f64>::zeros(n3, m);
        matmul(
            g.as_mut(),
            Accum::Replace,
            cc.as_ref(),
            inv.as_ref(),
            1.0,
            Par::Seq,
        );
        Ok(SpherePreconditioner {
            p,
            q,
            radius,
            coefs,
            scratch: Mutex::new(Scratch {
                ws,
                c: vec![0.0; m],
                y: vec![0.0; m],
                pv: vec![0.0; 4 * n],
                w: vec![0.0; n3],
            }),
            sht,
            inv,
            g,
        })
    }

    /// Whether this preconditioner was built for orders `(p, q)`, these coefficients and a
    /// radius within relative `radius_rtol` of `radius`.
    pub fn matches(
        &self,
        p: usize,
        q: usize,
        radius: f64,
        coefs: &StepCoefficients,
        radius_rtol: f64,
    ) -> bool {
        self.p == p
            && self.q == q
            && self.coefs == *coefs
            && (radius - self.radius).abs() <= radius_rtol * self.radius
    }

    /// The sphere's radius.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The operator coefficients it inverts.
    pub fn coefficients(&self) -> &StepCoefficients {
        &self.coefs
    }

    /// Bytes held by the dense factors (`(4n_c)² + 3n · 4n_c` doubles).
    pub fn memory_bytes(&self) -> usize {
        8 * (self.inv.nrows() * self.inv.ncols() + self.g.nrows() * self.g.ncols())
    }
}

impl Preconditioner for SpherePreconditioner {
    fn nrows(&self) -> usize {
        4 * self.sht.n_points()
    }

    fn apply(&self, v: &[f64], z: &mut [f64]) {
        let n = self.sht.n_points();
        let n3 = 3 * n;
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let Scratch { ws, c, y, pv, w } = &mut *guard;
        // Lengths are checked by the solver; the transforms cannot fail on them.
        if self.sht.forward(v, c, ws).is_err() || self.sht.inverse(c, pv, ws).is_err() || {
            matmul(
                MatMut::from_column_major_slice_mut(y, c.len(), 1),
                Accum::Replace,
                self.inv.as_ref(),
                MatRef::from_column_major_slice(c, c.len(), 1),
                1.0,
                Par::Seq,
            );
            self.sht.inverse(y, z, ws).is_err()
        } {
            z.fill(f64::NAN);
            return;
        }
        matmul(
            MatMut::from_column_major_slice_mut(w, n3, 1),
            Accum::Replace,
            self.g.as_ref(),
            MatRef::from_column_major_slice(c, c.len(), 1),
            1.0,
            Par::Seq,
        );
        let ainv = 1.0 / self.coefs.identity;
        for i in 0..n3 {
            z[i] += (v[i] - pv[i] - w[i]) * ainv;
        }
        for i in n3..4 * n {
            z[i] += v[i] - pv[i];
        }
    }
}
