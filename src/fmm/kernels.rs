//! The kernels of the N-body sums, with the normalisations of the `mobo fmm` contract
//! (`r = x − y`, viscosity `μ = 1`):
//!
//! * [`Laplace`]: `u(x) = Σ q_j / (4π|r|)`;
//! * [`LaplaceDoubleLayer`]: `u(x) = Σ (n_j·r) q_j / (4π|r|³)`;
//! * [`Stokeslet`]: `u(x) = Σ (1/8π) (I/|r| + r rᵀ/|r|³) f_j`;
//! * [`Stresslet`]: `u(x) = Σ (3/4π) (r·f_j)(r·n_j) r / |r|⁵` (density `f_j`, orientation `n_j`);
//! * [`Rpy`]: `u(x) = Σ M(r) f_j`, the Rotne–Prager–Yamakawa mobility with `M0 = 1/(6πa)`, both
//!   the `r ≥ 2a` and the overlapping `r < 2a` forms.
//!
//! Coincident points (`r = 0`): the singular kernels contribute nothing (the self term is left
//! out); RPY contributes its self mobility `M0 f_j`.
//!
//! Kernels are serial, branch-light functions of one pair; drivers loop over pairs.

/// The scalar coefficients `(f, g)` of the dimensionless RPY block `M/M0 = f I + g r̂r̂` at
/// distance `d > 0` for radius `a`: `r ≥ 2a`: `f = 3a/4d + a³/2d³`, `g = 3a/4d − 3a³/2d³`;
/// `r < 2a`: `f = 1 − 9d/32a`, `g = 3d/32a`.
#[inline]
pub fn rpy_coefficients(d: f64, a: f64) -> (f64, f64) {
    if d >= 2.0 * a {
        let s = a / d;
        let s3 = s * s * s;
        (0.75 * s + 0.5 * s3, 0.75 * s - 1.5 * s3)
    } else {
        let t = d / a;
        (1.0 - 9.0 * t / 32.0, 3.0 * t / 32.0)
    }
}

/// One kernel: how a source of given density (and orientation) acts at separation `r = x − y`.
pub trait Kernel: Sync {
    /// Name used on the command line.
    fn name(&self) -> &'static str;
    /// Components of the density per source.
    fn density_dim(&self) -> usize;
    /// Components of the result per target.
    fn output_dim(&self) -> usize;
    /// Whether sources carry an orientation (normal).
    fn needs_normals(&self) -> bool;
    /// Add the contribution of one source at `r ≠ 0` to `out`.
    fn accumulate(&self, r: [f64; 3], density: &[f64], normal: [f64; 3], out: &mut [f64]);
    /// Add the contribution of a source coincident with the target (`r = 0`).
    fn coincident(&self, _density: &[f64], _out: &mut [f64]) {}
    /// The kernel as a matrix at `r ≠ 0` (no normal): `out[a·de + b]` is output component `a`
    /// of a unit density in component `b` (`output_dim × density_dim`, both at most 4).
    fn tensor(&self, r: [f64; 3], out: &mut [f64]) {
        let (dt, de) = (self.output_dim(), self.density_dim());
        let (mut unit, mut o) = ([0.0; 4], [0.0; 4]);
        for b in 0..de {
            unit[..de].fill(0.0);
            unit[b] = 1.0;
            o[..dt].fill(0.0);
            self.accumulate(r, &unit[..de], [0.0; 3], &mut o[..dt]);
            for a in 0..dt {
                out[a * de + b] = o[a];
            }
        }
    }
    /// Add the field of a block of sources at every target (`output_dim` values per target in
    /// `out`). The default loops over pairs with [`Kernel::accumulate`]; the kernels of this
    /// module override it with the vectorised loops of [`super::p2p`].
    fn eval_block(&self, targets: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        let (dd, od) = (self.density_dim(), self.output_dim());
        let mut q = [0.0; 4];
        for (x, o) in targets.iter().zip(out.chunks_exact_mut(od)) {
            for j in 0..s.len() {
                for (c, v) in q.iter_mut().enumerate().take(dd) {
                    *v = s.q[c][j];
                }
                let r = [x[0] - s.x[j], x[1] - s.y[j], x[2] - s.z[j]];
                if r == [0.0; 3] {
                    self.coincident(&q[..dd], o);
                } else {
                    let n = if s.n[0].is_empty() {
                        [0.0; 3]
                    } else {
                        [s.n[0][j], s.n[1][j], s.n[2][j]]
                    };
                    self.accumulate(r, &q[..dd], n, o);
                }
            }
        }
    }
    /// As [`Kernel::eval_block`], allowed a relative error up to `tol` per pair (the near field
    /// of an FMM whose own error is far larger): the Laplace and Stokeslet loops then refine
    /// `1/|r|` by one Newton step instead of two where that stays within `tol`
    /// ([`super::p2p::Newton::within`]). The default is exact.
    fn eval_block_within(&self, targets: &[[f64; 3]], s: &SourceView, out: &mut [f64], tol: f64) {
        let _ = tol;
        self.eval_block(targets, s, out)
    }
    /// For a kernel symmetric under swapping source and target (`K(x − y) = K(y − x)`, the
    /// same density and output components): add block `b`'s field at block `a`'s points to
    /// `oa` and `a`'s at `b`'s to `ob` (both blocks sources and targets of one point set), each
    /// pair's kernel computed once, within `tol` as in [`Kernel::eval_block_within`]. `false`
    /// (nothing added) where the kernel has no such loop; the default.
    fn eval_mutual_within(
        &self,
        a: &SourceView,
        oa: &mut [f64],
        b: &SourceView,
        ob: &mut [f64],
        tol: f64,
    ) -> bool {
        let _ = (a, oa, b, ob, tol);
        false
    }
    /// Whether [`Kernel::eval_mutual_within`] runs for this kernel.
    fn has_mutual(&self) -> bool {
        false
    }
    /// Degree of homogeneity of density component `c`, `K(s r) = s^d K(r)` for `s > 0`, if the
    /// kernel is homogeneous (the FMM then builds its translation operators once for all levels).
    fn homogeneity(&self, _component: usize) -> Option<i32> {
        None
    }
}

use super::blocks::SourceView;
use super::p2p;
use super::FmmError;

const FOUR_PI: f64 = 4.0 * std::f64::consts::PI;
const EIGHT_PI: f64 = 8.0 * std::f64::consts::PI;

#[inline]
fn dot(a: [f64; 3], b: &[f64]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Laplace single layer.
#[derive(Clone, Copy, Debug, Default)]
pub struct Laplace;

impl Kernel for Laplace {
    fn name(&self) -> &'static str {
        "laplace"
    }
    fn density_dim(&self) -> usize {
        1
    }
    fn output_dim(&self) -> usize {
        1
    }
    fn needs_normals(&self) -> bool {
        false
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], q: &[f64], _n: [f64; 3], out: &mut [f64]) {
        let d = dot(r, &r).sqrt();
        out[0] += q[0] / (FOUR_PI * d);
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::laplace(t, s, out)
    }
    fn eval_block_within(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64], tol: f64) {
        let simd = p2p::Simd::best();
        p2p::laplace_with(simd, p2p::Newton::within(simd, tol, 1), t, s, out);
    }
    fn eval_mutual_within(
        &self,
        a: &SourceView,
        oa: &mut [f64],
        b: &SourceView,
        ob: &mut [f64],
        tol: f64,
    ) -> bool {
        let simd = p2p::Simd::best();
        p2p::laplace_mutual_with(simd, p2p::Newton::within(simd, tol, 1), a, oa, b, ob)
    }
    fn has_mutual(&self) -> bool {
        true
    }
    fn homogeneity(&self, _c: usize) -> Option<i32> {
        Some(-1)
    }
}

/// Laplace double layer.
#[derive(Clone, Copy, Debug, Default)]
pub struct LaplaceDoubleLayer;

impl Kernel for LaplaceDoubleLayer {
    fn name(&self) -> &'static str {
        "laplace-dl"
    }
    fn density_dim(&self) -> usize {
        1
    }
    fn output_dim(&self) -> usize {
        1
    }
    fn needs_normals(&self) -> bool {
        true
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], q: &[f64], n: [f64; 3], out: &mut [f64]) {
        let d2 = dot(r, &r);
        let d = d2.sqrt();
        out[0] += dot(n, &r) * q[0] / (FOUR_PI * d2 * d);
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::laplace_dl(t, s, out)
    }
}

/// Stokeslet (free-space Green's function of Stokes flow, `μ = 1`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Stokeslet;

impl Kernel for Stokeslet {
    fn name(&self) -> &'static str {
        "stokeslet"
    }
    fn density_dim(&self) -> usize {
        3
    }
    fn output_dim(&self) -> usize {
        3
    }
    fn needs_normals(&self) -> bool {
        false
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], f: &[f64], _n: [f64; 3], out: &mut [f64]) {
        let d2 = dot(r, &r);
        let inv = 1.0 / d2.sqrt();
        let rf = dot(r, f) * inv * inv;
        for k in 0..3 {
            out[k] += (f[k] + rf * r[k]) * inv / EIGHT_PI;
        }
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::stokeslet(t, s, out)
    }
    fn eval_block_within(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64], tol: f64) {
        let simd = p2p::Simd::best();
        p2p::stokeslet_with(simd, p2p::Newton::within(simd, tol, 3), t, s, out);
    }
    fn homogeneity(&self, _c: usize) -> Option<i32> {
        Some(-1)
    }
}

/// Stresslet (the Stokes double-layer kernel) with density `f` and orientation `n`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stresslet;

impl Kernel for Stresslet {
    fn name(&self) -> &'static str {
        "stresslet"
    }
    fn density_dim(&self) -> usize {
        3
    }
    fn output_dim(&self) -> usize {
        3
    }
    fn needs_normals(&self) -> bool {
        true
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], f: &[f64], n: [f64; 3], out: &mut [f64]) {
        let d2 = dot(r, &r);
        let d = d2.sqrt();
        let c = 3.0 / FOUR_PI * dot(r, f) * dot(n, &r) / (d2 * d2 * d);
        for k in 0..3 {
            out[k] += c * r[k];
        }
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::stresslet(t, s, out)
    }
}

/// Rotne–Prager–Yamakawa mobility of beads of radius `a`, `M0 = 1/(6πa)`.
#[derive(Clone, Copy, Debug)]
pub struct Rpy {
    /// Bead radius.
    pub radius: f64,
}

impl Kernel for Rpy {
    fn name(&self) -> &'static str {
        "rpy"
    }
    fn density_dim(&self) -> usize {
        3
    }
    fn output_dim(&self) -> usize {
        3
    }
    fn needs_normals(&self) -> bool {
        false
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], f: &[f64], _n: [f64; 3], out: &mut [f64]) {
        let d2 = dot(r, &r);
        let (ci, crr) = rpy_coefficients(d2.sqrt(), self.radius);
        let m0 = 1.0 / (6.0 * std::f64::consts::PI * self.radius);
        let rf = crr * dot(r, f) / d2;
        for k in 0..3 {
            out[k] += m0 * (ci * f[k] + rf * r[k]);
        }
    }
    fn coincident(&self, f: &[f64], out: &mut [f64]) {
        let m0 = 1.0 / (6.0 * std::f64::consts::PI * self.radius);
        for k in 0..3 {
            out[k] += m0 * f[k];
        }
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::rpy(t, s, out, self.radius)
    }
}

/// Equivalent kernel for Stokes double layers: a Stokeslet plus a point source,
/// `u(x) = Σ (1/8π)(I/|r| + r rᵀ/|r|³) f_j + q_j r/(4π|r|³)`, density `(f, q)`. The source term
/// carries the net flux of the trace part of a stresslet `f ⊗ n`, which divergence-free
/// Stokeslets cannot represent.
#[derive(Clone, Copy, Debug, Default)]
pub struct StokesletSource;

impl Kernel for StokesletSource {
    fn name(&self) -> &'static str {
        "stokeslet+source"
    }
    fn density_dim(&self) -> usize {
        4
    }
    fn output_dim(&self) -> usize {
        3
    }
    fn needs_normals(&self) -> bool {
        false
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], fq: &[f64], n: [f64; 3], out: &mut [f64]) {
        Stokeslet.accumulate(r, &fq[..3], n, out);
        let d2 = dot(r, &r);
        let c = fq[3] / (FOUR_PI * d2 * d2.sqrt());
        for k in 0..3 {
            out[k] += c * r[k];
        }
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::stokeslet_source(t, s, out)
    }
    fn homogeneity(&self, c: usize) -> Option<i32> {
        Some(if c < 3 { -1 } else { -2 })
    }
}

/// The RPY far field seen from one side: `(1 + a²/6 ∇²) G`, `G` the Stokeslet, i.e.
/// `u = (1/8π)[(1/r + a²/3r³) f + (1/r³ − a²/r⁵)(r·f) r]`. The FMM applies it between beads and
/// equivalent surfaces (P2M, P2L, M2P, L2P); applied on both sides it composes to the RPY
/// tensor for `r ≥ 2a`, `(1 + a²/3 ∇²) G`.
#[derive(Clone, Copy, Debug)]
pub struct RpyFar {
    /// Bead radius.
    pub radius: f64,
}

impl Kernel for RpyFar {
    fn name(&self) -> &'static str {
        "rpy-far"
    }
    fn density_dim(&self) -> usize {
        3
    }
    fn output_dim(&self) -> usize {
        3
    }
    fn needs_normals(&self) -> bool {
        false
    }
    #[inline]
    fn accumulate(&self, r: [f64; 3], f: &[f64], _n: [f64; 3], out: &mut [f64]) {
        let d2 = dot(r, &r);
        let inv = 1.0 / d2.sqrt();
        let a2 = self.radius * self.radius;
        let ci = inv * (1.0 + a2 / 3.0 * inv * inv) / EIGHT_PI;
        let crr = inv * inv * inv * (1.0 - a2 * inv * inv) * dot(r, f) / EIGHT_PI;
        for k in 0..3 {
            out[k] += ci * f[k] + crr * r[k];
        }
    }
    fn eval_block(&self, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
        p2p::rpy_far(t, s, out, self.radius)
    }
}

/// The sums `mobo fmm` offers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FmmKernel {
    /// `Σ q/(4π|r|)`.
    Laplace,
    /// `Σ (n·r) q/(4π|r|³)`.
    LaplaceDoubleLayer,
    /// `Σ (1/8π)(I/|r| + r rᵀ/|r|³) f`.
    Stokeslet,
    /// `Σ (3/4π)(r·f)(r·n) r/|r|⁵`.
    Stresslet,
    /// Rotne–Prager–Yamakawa with bead radius `radius`.
    Rpy {
        /// Bead radius `a`.
        radius: f64,
    },
}

impl FmmKernel {
    /// Parse a command-line name (`laplace`, `laplace-dl`, `stokeslet`, `stresslet`, `rpy`).
    pub fn from_name(name: &str, radius: Option<f64>) -> Result<Self, FmmError> {
        Ok(match name {
            "laplace" => FmmKernel::Laplace,
            "laplace-dl" => FmmKernel::LaplaceDoubleLayer,
            "stokeslet" => FmmKernel::Stokeslet,
            "stresslet" => FmmKernel::Stresslet,
            "rpy" => {
                let a = radius.ok_or_else(|| FmmError::Shape("rpy needs a radius".into()))?;
                if !(a > 0.0 && a.is_finite()) {
                    return Err(FmmError::Shape(format!(
                        "rpy radius must be positive, got {a}"
                    )));
                }
                FmmKernel::Rpy { radius: a }
            }
            other => return Err(FmmError::Shape(format!("unknown kernel '{other}'"))),
        })
    }

    /// The kernel applied between points (P2P, and the direct sum).
    pub fn near(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Laplace => Box::new(Laplace),
            FmmKernel::LaplaceDoubleLayer => Box::new(LaplaceDoubleLayer),
            FmmKernel::Stokeslet => Box::new(Stokeslet),
            FmmKernel::Stresslet => Box::new(Stresslet),
            FmmKernel::Rpy { radius } => Box::new(Rpy { radius }),
        }
    }

    /// Sources to check surfaces (P2M, P2L).
    pub(super) fn far_source(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Rpy { radius } => Box::new(RpyFar { radius }),
            _ => self.near(),
        }
    }

    /// Equivalent densities to check surfaces (M2M, M2L, L2L).
    pub(super) fn equivalent(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Laplace | FmmKernel::LaplaceDoubleLayer => Box::new(Laplace),
            FmmKernel::Stokeslet | FmmKernel::Rpy { .. } => Box::new(Stokeslet),
            FmmKernel::Stresslet => Box::new(StokesletSource),
        }
    }

    /// Equivalent densities to targets (L2P, M2P).
    pub(super) fn far_target(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Rpy { radius } => Box::new(RpyFar { radius }),
            _ => self.equivalent(),
        }
    }

    /// Relative cut-off of the truncated-SVD fits (measured: Laplace keeps improving to
    /// 1e-13; Stokes kernels are best near 1e-10, round-off in the fits dominates below).
    pub fn rcond(&self) -> f64 {
        match self {
            FmmKernel::Laplace | FmmKernel::LaplaceDoubleLayer => 1e-13,
            _ => 1e-10,
        }
    }

    /// Default leaf size (points per leaf, sources plus targets), balancing P2P against the
    /// translations: measured on 10⁵ and 10⁶ points of the uniform and sphere clouds
    /// (examples/fmm_probe). Larger leaves also keep uniform clouds off half-refined levels,
    /// whose W and X lists cost more than they save.
    pub fn default_leaf_size(&self, order: usize) -> usize {
        100 * order.max(4)
    }

    /// [`FmmKernel::default_leaf_size`] where the targets are the sources (`same_points`). A
    /// kernel whose near field then evaluates each pair of leaves once for both directions
    /// ([`MutualPairs`](super::near_pairs::MutualPairs), Laplace, on one rank) pays half as
    /// much per pair in the P2P, so the balance against the translations moves to leaves √2
    /// larger. `mobo fmm` takes them on
    /// every rank count (the same tree, so K ranks give one rank's values to round-off).
    /// Measured (2·10⁵ points, Laplace at 6 digits, 2 threads, 3 interleaved rounds, s per
    /// evaluation, leaves of 800 against 1131 sources plus targets, i.e. 400 against 566
    /// points): uniform cube 0.38–0.44 against 0.28–0.31, spheres 0.33–0.40 against
    /// 0.33–0.34, Gaussian blobs 0.42–0.43 against 0.43–0.47.
    pub fn default_leaf_size_for(&self, order: usize, same_points: bool) -> usize {
        let base = self.default_leaf_size(order);
        if same_points && self.near().has_mutual() {
            (base as f64 * std::f64::consts::SQRT_2).round() as usize
        } else {
            base
        }
    }
}
