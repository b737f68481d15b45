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
//! ## What is built
//!
//! The operator is built numerically in SH-coefficient space, from the same discrete `S, D, B,
//! T, Div` as the step (so its inverse is exact for the discrete sphere, to rounding): with `F`
//! the forward transform (grid → the `n_c = (p+1)² − 1` coefficients of each of the 4 fields
//! `[x | y | z | σ]`) and `F⁻¹` the synthesis, `C = A_R F⁻¹` (`4n × 4n_c`: the local operators
//! applied once per coefficient, the `S`/`D` products as one GEMM each) and
//! `A_bb = F C` (`4n_c × 4n_c`).
//!
//! **Block structure.** Rotations about the `z` axis act on a degree-`l`, order-`m` coefficient
//! of `u_z` or `σ` with phase `e^{imα}`, and on `u_± = u_x ± i u_y` with total order
//! `M = m ± 1`. In the real basis, per `(l, m)` with `1 ≤ m < p`, the orthogonal map `Q`
//!
//! ```text
//!     (x_c, x_s, y_c, y_s) ↦ ((x_c + y_s), (x_c − y_s), (x_s − y_c), (x_s + y_c)) / √2
//! ```
//!
//! (`x_c, x_s` the `cos mφ`, `sin mφ` coefficients of `u_x`) gives fields of total order
//! `|M| = m+1, m−1, m+1, m−1`. The sphere and its grid are also symmetric under `y → −y`
//! (`φ → −φ`) and `z → −z` (the Gauss nodes are symmetric), so `B = Q A_bb Qᵀ` is
//! block-diagonal by `(|M|, φ-parity, z-parity)`. The blocks are found as the connected
//! components of `|B_ij| > 10⁻¹¹ max|B|` (no index bookkeeping to get wrong; the largest entry
//! left out is returned by [`SpherePreconditioner::dropped_relative`] and is at rounding level,
//! ~1e-14: tests/timestep_precond.rs) and inverted one by one. Measured: p = 6: 32 blocks, the
//! largest 13; p = 8: 42, 17; p = 12: 62 blocks, the largest 25 = 2(p+1)+1 of 4n_c = 672.
//!
//! **The grid complement.** The grid space is larger than the coefficient space (`n > n_c`). On
//! its complement `ker F` the discrete operator is `a I` on positions (`B`, `Div`, `D` see only
//! `F X`) and zero on tensions (`T` sees only `F σ`), so there `M⁻¹` is `1/a` on positions and the
//! identity on tensions:
//!
//! ```text
//!     M⁻¹ v = F⁻¹ Qᵀ B⁻¹ Q F v + [ (v_X − F⁻¹F v_X)/a ; v_σ − F⁻¹F v_σ ].
//! ```
//!
//! (The single layer of a degree-`p` density has some degree-`p+1` content, which lands in the
//! complement: on the sphere `A M⁻¹ = I + N` with `N` mapping into the complement and `N² = 0`,
//! so GMRES needs at most two iterations; it takes one at the tolerances tested.)
//!
//! The constant tension does nothing on a sphere (`T 1 = 2H n = −(2/R) n` and `S[n] = 0` on
//! every closed surface), so `A_bb` is singular in that one column; the preconditioner uses
//! `A_bb + e eᵀ` (`e` the unit vector of the `σ₀₀` coefficient), which changes nothing else.
//!
//! **Cost.** Build (once per process for each sphere while cells hold it, shared by all cells
//! of that size and coefficients through [`shared`]; rebuilt only when `R`, `τ`, `κ`, `μ` or `λ` change, and
//! the drift correction keeps the area, hence `R`, fixed): `4n_c` applications of the local
//! operators, one `(3n)² × 4n_c` GEMM with `S` (and one with `D` when `λ ≠ 1`), the rotation
//! and the block LUs (`Σ_k n_k³`): p = 12 in ≈ 0.45 s. Memory: `Σ_k n_k² = O(p³)` doubles
//! (p = 12: 87 kB; the dense inverse would be 3.6 MB). One application: three transforms of four
//! fields at order `p` (`O(p³)`) and the block products (`2 Σ_k n_k² = O(p³)` flops), well below
//! one product with the dense single layer (`2 (3n)² = O(p⁴)`).

use std::sync::{Arc, Mutex, Weak};

use crate::lu_pivots;
use faer::linalg::matmul::matmul;
use faer::linalg::solvers::DenseSolveCore;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::{Preconditioner, TimestepError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
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
    /// Whether `other` has the same operator coefficients apart from `τ` (the identity and
    /// double-layer coefficients, the bending modulus and the viscosity).
    pub fn same_operator(&self, other: &StepCoefficients) -> bool {
        self.identity == other.identity
            && self.double_layer == other.double_layer
            && self.bending_modulus == other.bending_modulus
            && self.viscosity == other.viscosity
    }

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
    /// Gathered block input and output (largest block).
    bi: Vec<f64>,
    bo: Vec<f64>,
}

impl Scratch {
    /// Scratch for `m = 4n_c` coefficients and blocks of up to `largest`.
    fn new(sht: &ShTransform, m: usize, largest: usize) -> Self {
        Scratch {
            ws: sht.workspace(),
            c: vec![0.0; m],
            y: vec![0.0; m],
            pv: vec![0.0; 4 * sht.n_points()],
            bi: vec![0.0; largest],
            bo: vec![0.0; largest],
        }
    }
}

/// The inverse step operator of a sphere (see the module docs), a right preconditioner of the
/// step of a cell of the same area.
pub struct SpherePreconditioner {
    p: usize,
    q: usize,
    radius: f64,
    coefs: StepCoefficients,
    /// The layer it was assembled with: quadrature order, rotation, far-side settings.
    layer_key: (usize, RotationAlgorithm, FarSideParams),
    sht: ShTransform,
    /// The `x`/`y` coefficient pairs mixed by `Q` (see [`Self::build`]).
    pairs: Vec<[usize; 4]>,
    /// Blocks of `Q (A_bb + e eᵀ) Qᵀ`: indices (in the rotated basis) and inverses.
    blocks: Vec<(Vec<usize>, Mat<f64>)>,
    /// Largest entry left out of the blocks, relative to the largest entry.
    dropped: f64,
    /// Scratch for the applications, one per thread applying at once (taken and put back per
    /// application), so that one preconditioner can serve many cells on many threads.
    scratch: Mutex<Vec<Scratch>>,
    /// `(4n_c, largest block)`: the sizes of a new scratch.
    scratch_sizes: (usize, usize),
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
        // A_bb = F C.
        let mut abb = Mat::<f64>::zeros(m, m);
        let mut coef = vec![0.0; 4 * nc];
        for j in 0..m {
            let o = &out[j * 4 * n..(j + 1) * 4 * n];
            if !o.iter().all(|v| v.is_finite()) {
                return Err(TimestepError::NonFinite {
                    what: "sphere step operator",
                });
            }
            sht.forward(o, &mut coef, &mut ws)
                .map_err(VesicleError::from)?;
            for (i, c) in coef.iter().enumerate() {
                abb[(i, j)] = *c;
            }
        }
        drop(out);
        // The constant tension is a null direction on the sphere (see the module docs).
        let s00 = 3 * nc;
        abb[(s00, s00)] += 1.0;
        // B = Q A_bb Qᵀ: rotate the x/y pairs into the basis of total order M.
        let pairs = xy_pairs(&sht, nc);
        rotate_rows(&mut abb, &pairs);
        let mut bt = abb.transpose().to_owned();
        rotate_rows(&mut bt, &pairs);
        let b = bt.transpose().to_owned();
        drop((abb, bt));
        // Connected components of |B_ij| > thr·max|B| (union–find).
        let mut bmax = 0.0_f64;
        for jj in 0..m {
            for ii in 0..m {
                bmax = bmax.max(b[(ii, jj)].abs());
            }
        }
        let thr = BLOCK_THRESHOLD * bmax;
        let mut parent: Vec<usize> = (0..m).collect();
        fn find(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for jj in 0..m {
            for ii in 0..m {
                if ii != jj && b[(ii, jj)].abs() > thr {
                    let (ri, rj) = (find(&mut parent, ii), find(&mut parent, jj));
                    if ri != rj {
                        parent[ri] = rj;
                    }
                }
            }
        }
        let mut comp_of = vec![usize::MAX; m];
        let mut comps: Vec<Vec<usize>> = Vec::new();
        for i in 0..m {
            let r = find(&mut parent, i);
            if comp_of[r] == usize::MAX {
                comp_of[r] = comps.len();
                comps.push(Vec::new());
            }
            comps[comp_of[r]].push(i);
        }
        let mut which = vec![0usize; m];
        for (k, c) in comps.iter().enumerate() {
            for &i in c {
                which[i] = k;
            }
        }
        let mut dropped = 0.0_f64;
        for jj in 0..m {
            for ii in 0..m {
                if which[ii] != which[jj] {
                    dropped = dropped.max(b[(ii, jj)].abs());
                }
            }
        }
        let mut blocks = Vec::with_capacity(comps.len());
        let mut largest = 0;
        for (index, idx) in comps.into_iter().enumerate() {
            let k = idx.len();
            largest = largest.max(k);
            let blk = Mat::<f64>::from_fn(k, k, |i, j| b[(idx[i], idx[j])]);
            let lu = blk.partial_piv_lu();
            let pivot_ratio = lu_pivots::pivot_ratio(lu.U());
            if !lu_pivots::accepts(pivot_ratio, lu_pivots::roundoff_floor(k)) {
                return Err(TimestepError::SingularBlock {
                    index,
                    size: k,
                    pivot_ratio,
                });
            }
            blocks.push((idx, lu.inverse()));
        }
        Ok(SpherePreconditioner {
            p,
            q,
            radius,
            coefs,
            layer_key: layer_key(layer),
            scratch: Mutex::new(vec![Scratch::new(&sht, m, largest)]),
            scratch_sizes: (m, largest),
            sht,
            pairs,
            blocks,
            dropped: dropped / bmax,
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

    /// Bytes held by the inverted blocks (`Σ_k n_k²` doubles).
    pub fn memory_bytes(&self) -> usize {
        8 * self
            .blocks
            .iter()
            .map(|(i, _)| i.len() * i.len())
            .sum::<usize>()
    }

    /// Sizes of the diagonal blocks (in the rotated coefficient basis).
    pub fn block_sizes(&self) -> Vec<usize> {
        self.blocks.iter().map(|(i, _)| i.len()).collect()
    }

    /// The largest entry of the sphere's coefficient-space operator outside the blocks, relative
    /// to its largest entry (the part the block-diagonal inverse leaves out; rounding level).
    pub fn dropped_relative(&self) -> f64 {
        self.dropped
    }
}

/// What of a layer its operators depend on besides the surface (see [`shared`]).
fn layer_key(layer: &SelfInteraction) -> (usize, RotationAlgorithm, FarSideParams) {
    (
        layer.quadrature_order(),
        layer.rotation_algorithm(),
        layer.far_side_params(),
    )
}

/// The sphere preconditioners made by [`shared`], while some cell holds them.
static SHARED: Mutex<Vec<Weak<SpherePreconditioner>>> = Mutex::new(Vec::new());

/// The sphere preconditioner for exactly `(p, q, radius, coefs)` and the layer's quadrature
/// order, rotation and far-side settings, shared by every cell of the process that asks for
/// it: built by the first (with `membrane` and `layer`, as [`SpherePreconditioner::build`]),
/// then handed out while some cell holds it (and built again after the last one lets go). The build is a function of that key alone, so a cell gets the preconditioner
/// it would have built itself (the same steps bit for bit), and cells of one shape and size pay
/// for one build (≈ 0.3–0.45 s at p = 12) instead of one each. Threads that ask at the same
/// moment may each build one; the first kept serves later requests. Returns whether this call
/// built it.
pub fn shared(
    membrane: &mut Membrane,
    layer: &mut SelfInteraction,
    radius: f64,
    coefs: StepCoefficients,
) -> Result<(Arc<SpherePreconditioner>, bool), TimestepError> {
    let (p, q, layer_key) = (
        membrane.order(),
        membrane.upsampled_order(),
        layer_key(layer),
    );
    let same = |m: &SpherePreconditioner| {
        m.p == p && m.q == q && m.radius == radius && m.coefs == coefs && m.layer_key == layer_key
    };
    let found = SHARED
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .iter()
        .filter_map(Weak::upgrade)
        .find(|m| same(m));
    if let Some(m) = found {
        return Ok((m, false));
    }
    let built = Arc::new(SpherePreconditioner::build(membrane, layer, radius, coefs)?);
    let mut kept = SHARED.lock().unwrap_or_else(|e| e.into_inner());
    kept.retain(|w| w.strong_count() > 0);
    kept.push(Arc::downgrade(&built));
    Ok((built, true))
}

impl Preconditioner for SpherePreconditioner {
    fn nrows(&self) -> usize {
        4 * self.sht.n_points()
    }

    fn apply(&self, v: &[f64], z: &mut [f64]) {
        let taken = self.scratch.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let mut scratch = taken.unwrap_or_else(|| {
            let (m, largest) = self.scratch_sizes;
            Scratch::new(&self.sht, m, largest)
        });
        self.apply_with(v, z, &mut scratch);
        self.scratch
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(scratch);
    }
}

impl SpherePreconditioner {
    fn apply_with(&self, v: &[f64], z: &mut [f64], scratch: &mut Scratch) {
        let Scratch {
            ws,
            c,
            y,
            pv,
            bi,
            bo,
        } = scratch;
        // Lengths are checked by the solver; the transforms cannot fail on them.
        if self.sht.forward(v, c, ws).is_err() || self.sht.inverse(c, pv, ws).is_err() {
            z.fill(f64::NAN);
            return;
        }
        rotate(c, &self.pairs, false);
        for (idx, inv) in &self.blocks {
            let k = idx.len();
            for (b, &i) in bi[..k].iter_mut().zip(idx) {
                *b = c[i];
            }
            matmul(
                MatMut::from_column_major_slice_mut(&mut bo[..k], k, 1),
                Accum::Replace,
                inv.as_ref(),
                MatRef::from_column_major_slice(&bi[..k], k, 1),
                1.0,
                Par::Seq,
            );
            for (b, &i) in bo[..k].iter().zip(idx) {
                y[i] = *b;
            }
        }
        rotate(y, &self.pairs, true);
        if self.sht.inverse(y, z, ws).is_err() {
            z.fill(f64::NAN);
            return;
        }
        add_grid_complement(v, pv, self.coefs.identity, z);
    }
}

/// `z ← z + [(v_X − F⁻¹F v_X)/a ; v_σ − F⁻¹F v_σ]`: the inverse step operator on the grid
/// complement `ker F` (`a` on positions, zero on tensions; module docs), with `pv = F⁻¹F v`
/// (`4n` values: `3n` positions, then `n` tensions). Shared with the cell's own preconditioner.
pub(crate) fn add_grid_complement(v: &[f64], pv: &[f64], identity: f64, z: &mut [f64]) {
    let n3 = 3 * (v.len() / 4);
    let ainv = 1.0 / identity;
    for i in 0..n3 {
        z[i] += (v[i] - pv[i]) * ainv;
    }
    for i in n3..v.len() {
        z[i] += v[i] - pv[i];
    }
}

/// Relative size below which an entry of the rotated sphere operator counts as zero when its
/// blocks are found (the entries that vanish by symmetry are at rounding level, ~1e-15).
const BLOCK_THRESHOLD: f64 = 1e-11;

/// The `x`/`y` coefficient quadruples `[x cos, x sin, y cos, y sin]` of every `(l, m)` with
/// `1 ≤ m < p` (indices into the `4n_c` coefficients `[x | y | z | σ]`).
fn xy_pairs(sht: &ShTransform, nc: usize) -> Vec<[usize; 4]> {
    let layout = sht.layout();
    let p = sht.order();
    let mut out = Vec::new();
    for m in 1..p {
        for l in m..=p {
            if let (Some(ic), Some(is)) =
                (layout.index(l, m as isize), layout.index(l, -(m as isize)))
            {
                out.push([ic, is, nc + ic, nc + is]);
            }
        }
    }
    out
}

/// `c ← Q c` (or `Qᵀ c` if `transpose`), `Q` mixing each quadruple `(xc, xs, yc, ys)` into
/// `((xc + ys), (xc − ys), (xs − yc), (xs + yc))/√2`: the real forms of the fields
/// `u_x ± i u_y ∝ e^{±i(m±1)φ}` of total order `|M| = m ± 1` (module docs).
fn rotate(c: &mut [f64], pairs: &[[usize; 4]], transpose: bool) {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    for &[xc, xs, yc, ys] in pairs {
        let (a, b, cc, d) = (c[xc], c[xs], c[yc], c[ys]);
        if transpose {
            // Qᵀ = Q⁻¹: xc = (e1 + e2)/√2, ys = (e1 − e2)/√2, xs = (e3 + e4)/√2, yc = (e4 − e3)/√2.
            c[xc] = h * (a + b);
            c[ys] = h * (a - b);
            c[xs] = h * (cc + d);
            c[yc] = h * (d - cc);
        } else {
            c[xc] = h * (a + d);
            c[xs] = h * (a - d);
            c[yc] = h * (b - cc);
            c[ys] = h * (b + cc);
        }
    }
}

/// `A ← Q A` (rows rotated as in [`rotate`]).
fn rotate_rows(a: &mut Mat<f64>, pairs: &[[usize; 4]]) {
    let mut col = vec![0.0; a.nrows()];
    for j in 0..a.ncols() {
        for (i, v) in col.iter_mut().enumerate() {
            *v = a[(i, j)];
        }
        rotate(&mut col, pairs, false);
        for (i, v) in col.iter().enumerate() {
            a[(i, j)] = *v;
        }
    }
}
