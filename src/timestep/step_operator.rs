//! The linear operators of a step: the dense (or matrix-free) single and double layers as
//! products, the elastic Jacobian by central differences, and the inextensible step operator
//! `[X; σ] ↦ [a X − c_D D X − τ S (B X + T σ + J X); Div X]` of [`super::semi_implicit`] as a
//! [`LinearOperator`] whose batched product ([`LinearOperator::apply_batch`]) applies the
//! dense layers to all columns as one matrix product (what building a cell's own
//! preconditioner, [`super::cell_preconditioner`], costs: one GEMM instead of `4n_c` GEMVs).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::operator_storage::OperatorStorage;
use super::step_engine::{ElasticWork, OperatorWork, ProductWork};
use super::LinearOperator;
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::coefficient_operator::add_product;
use crate::vesicle::layer::LayerKernel;
use crate::vesicle::skalak::SkalakParams;
use crate::vesicle::VesicleError;

/// An operator of a step: stored dense (as the storage says), or its kernel (matrix-free).
#[derive(Clone, Copy)]
pub(crate) enum StepOperator<'a> {
    /// Stored dense (grid or coefficient space, as the storage says).
    Dense(&'a [f64]),
    /// Applied matrix-free.
    Kernel(LayerKernel),
}

/// A cell's layers on its own surface, `S f` and, where asked, `D g`
/// ([`InextensibleOperator::layer_values`]); `None` where they are not stored dense.
pub(crate) type LayerValues = Option<(Vec<f64>, Option<Vec<f64>>)>;

/// One term `β K x` of a product: the operator, the input (a grid vector, `3n`) and `β`.
pub(crate) type Term<'a> = (StepOperator<'a>, &'a [f64], f64);

/// `y ← y + β_S S x_S + β_D D x_D` (the double-layer term optional; grid vectors, `3n` each):
/// a GEMV each on the grid, `y ← y + I (Σ β K F x)` in coefficient space, or matrix-free
/// products on the surface `surface` (coefficients).
pub(crate) fn apply_operators(
    storage: OperatorStorage,
    sht: &ShTransform,
    work: &mut ProductWork,
    surface: &[f64],
    single: Term<'_>,
    double: Option<Term<'_>>,
    y: &mut [f64],
) -> Result<(), VesicleError> {
    let ProductWork {
        layer,
        ws,
        xc,
        yc,
        yg,
    } = work;
    let terms = std::iter::once(single).chain(double);
    match storage {
        OperatorStorage::Coefficients => {
            yc.fill(0.0);
            for (k, x, beta) in terms {
                if let StepOperator::Dense(k) = k {
                    sht.forward(x, xc, ws)?;
                    add_product(k, xc, yc, beta);
                }
            }
            sht.inverse(yc, yg, ws)?;
            for (a, b) in y.iter_mut().zip(yg.iter()) {
                *a += b;
            }
        }
        OperatorStorage::Grid | OperatorStorage::MatrixFree => {
            for (k, x, beta) in terms {
                match k {
                    StepOperator::Dense(k) => add_grid_product(sht, ws, xc, k, x, y, beta)?,
                    StepOperator::Kernel(kernel) => {
                        layer.apply(kernel, surface, x, yg)?;
                        for (a, b) in y.iter_mut().zip(yg.iter()) {
                            *a += beta * b;
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// `y ← y + β A x` for a grid operator as [`OperatorStorage::Grid`] keeps it: the rows `P`
/// over the density's coefficients (`3n × 3n_c`, row-major;
/// [`crate::vesicle::SelfInteraction::assemble_rows`]), applied as `P (F x)`, or, without
/// upsampling (`q = p`), the full `A` (`3n × 3n`). `xc` is `3n_c` of scratch.
pub(crate) fn add_grid_product(
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    xc: &mut [f64],
    k: &[f64],
    x: &[f64],
    y: &mut [f64],
    beta: f64,
) -> Result<(), VesicleError> {
    let (n3, nc3) = (x.len(), 3 * sht.n_coefs());
    if k.len() == n3 * nc3 {
        sht.forward(x, xc, ws)?;
        matmul(
            MatMut::from_column_major_slice_mut(y, n3, 1),
            Accum::Add,
            MatRef::from_row_major_slice(k, n3, nc3),
            MatRef::from_column_major_slice(xc, nc3, 1),
            beta,
            Par::Seq,
        );
    } else {
        add_product(k, x, y, beta);
    }
    Ok(())
}

/// `f ← f + J x`: the directional derivative of the elastic force at the surface `xstar`
/// (coefficients) along the grid vector `x` (`3n`), by a central difference with `ε|x|` a
/// [`JACOBIAN_STEP`] fraction of `size` (the engine `el` holds the reference surface).
#[allow(clippy::too_many_arguments)] // the pieces of a lent engine, borrowed separately
pub(crate) fn add_elastic_jacobian(
    el: &mut ElasticWork,
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    par: &SkalakParams,
    xstar: &[f64],
    size: f64,
    x: &[f64],
    f: &mut [f64],
) -> Result<(), VesicleError> {
    sht.forward(x, &mut el.dir, ws)?;
    let norm = el.dir.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm == 0.0 {
        return Ok(());
    }
    let eps = JACOBIAN_STEP * size / norm;
    for sign in [1.0, -1.0] {
        for ((d, s), v) in el.dc.iter_mut().zip(xstar).zip(&el.dir) {
            *d = s + sign * eps * v;
        }
        el.membrane.set_geometry(&el.dc)?;
        el.membrane.skalak_force(par, &mut el.fp)?;
        let w = sign / (2.0 * eps);
        for (fi, p) in f.iter_mut().zip(&el.fp) {
            *fi += w * p;
        }
    }
    Ok(())
}

/// The central-difference step of a capsule's elastic Jacobian, relative to the cell's size:
/// truncation `~10⁻¹⁰` and round-off `~10⁻¹¹` relative to `J x`.
pub(crate) const JACOBIAN_STEP: f64 = 1e-5;

/// The step operator of an inextensible cell on `z = [X; σ]` (grid vectors, `3n` positions
/// component-major then `n` tensions):
///
/// ```text
///     A z = [ a X − c_D D X − τ S (B X + T σ + J X) ;  Div X ]
/// ```
///
/// with the operators frozen at `X*` (`xstar`, coefficients) and `J` (the linearised shear
/// elasticity) only once [`InextensibleOperator::enable_jacobian`] is called. A failure of the
/// membrane operators writes NaN into the output and is kept for
/// [`InextensibleOperator::take_failure`].
pub(crate) struct InextensibleOperator<'a> {
    n: usize,
    work: &'a Mutex<OperatorWork>,
    sht: &'a ShTransform,
    storage: OperatorStorage,
    xstar: &'a [f64],
    s_op: StepOperator<'a>,
    d_op: Option<StepOperator<'a>>,
    /// `a = (1+λ)/2`, `c_D = 1 − λ`, `τ`, `κ_b`.
    a_id: f64,
    c_d: f64,
    tau: f64,
    kappa: f64,
    /// The shear elasticity of the Jacobian (its engine made and its reference set).
    jacobian: Option<SkalakParams>,
    /// The cell's size, the scale of the Jacobian's difference step.
    size: f64,
    with_jacobian: AtomicBool,
    failure: Mutex<Option<VesicleError>>,
}

impl<'a> InextensibleOperator<'a> {
    /// The operator without the Jacobian (see the type's docs for the fields).
    #[allow(clippy::too_many_arguments)] // the pieces of a lent engine and the step's scalars
    pub fn new(
        n: usize,
        work: &'a Mutex<OperatorWork>,
        sht: &'a ShTransform,
        storage: OperatorStorage,
        xstar: &'a [f64],
        (s_op, d_op): (StepOperator<'a>, Option<StepOperator<'a>>),
        [a_id, c_d, tau, kappa]: [f64; 4],
        jacobian: Option<SkalakParams>,
        size: f64,
    ) -> Self {
        InextensibleOperator {
            n,
            work,
            sht,
            storage,
            xstar,
            s_op,
            d_op,
            a_id,
            c_d,
            tau,
            kappa,
            jacobian,
            size,
            with_jacobian: AtomicBool::new(false),
            failure: Mutex::new(None),
        }
    }

    /// Add `−τ S J X` to every later product.
    pub fn enable_jacobian(&self) {
        self.with_jacobian.store(true, Ordering::Relaxed);
    }

    /// The first failure of the membrane operators, if any (taken).
    pub fn take_failure(&self) -> Option<VesicleError> {
        self.failure
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
    }

    fn fail(&self, e: VesicleError) {
        let mut f = self.failure.lock().unwrap_or_else(|e| e.into_inner());
        if f.is_none() {
            *f = Some(e);
        }
    }

    /// The local part of one column: `f = B X + T σ (+ J X)`, `y_X = a X`, `y_σ = Div X`.
    fn local(
        &self,
        w: &mut OperatorWork,
        z: &[f64],
        f: &mut [f64],
        y: &mut [f64],
    ) -> Result<(), VesicleError> {
        let n3 = 3 * self.n;
        let (x, sigma) = z.split_at(n3);
        let OperatorWork {
            membrane,
            ft,
            products,
            elastic,
            ..
        } = w;
        // A zero field contributes nothing (the unit columns of a preconditioner build are
        // zero in all but one field): skip its operators.
        let x_zero = x.iter().all(|v| *v == 0.0);
        if x_zero {
            f.fill(0.0);
            y[n3..].fill(0.0);
        } else {
            membrane.bending_linear(self.kappa, x, f)?;
            membrane.surface_divergence(x, &mut y[n3..])?;
        }
        if sigma.iter().any(|v| *v != 0.0) {
            membrane.tension_force(sigma, ft)?;
            for (a, t) in f.iter_mut().zip(ft.iter()) {
                *a += t;
            }
        }
        if let (Some(par), Some(el), true, false) = (
            &self.jacobian,
            elastic.as_mut(),
            self.with_jacobian.load(Ordering::Relaxed),
            x_zero,
        ) {
            add_elastic_jacobian(
                el,
                self.sht,
                &mut products.ws,
                par,
                self.xstar,
                self.size,
                x,
                f,
            )?;
        }
        for (yi, xi) in y[..n3].iter_mut().zip(x) {
            *yi = self.a_id * xi;
        }
        Ok(())
    }

    fn apply_one(&self, z: &[f64], y: &mut [f64]) -> Result<(), VesicleError> {
        let n3 = 3 * self.n;
        let mut guard = self.work.lock().unwrap_or_else(|e| e.into_inner());
        let w = &mut *guard;
        let mut f = std::mem::take(&mut w.fb);
        let r = self.local(w, z, &mut f, y).and_then(|_| {
            apply_operators(
                self.storage,
                self.sht,
                &mut w.products,
                self.xstar,
                (self.s_op, &f, -self.tau),
                self.d_op.map(|d| (d, &z[..n3], -self.c_d)),
                &mut y[..n3],
            )
        });
        w.fb = f;
        r
    }

    /// `k` columns with the dense layers as one matrix product each.
    fn apply_dense_batch(&self, z: &[f64], y: &mut [f64], k: usize) -> Result<(), VesicleError> {
        let (n3, n4) = (3 * self.n, 4 * self.n);
        let mut guard = self.work.lock().unwrap_or_else(|e| e.into_inner());
        let w = &mut *guard;
        let mut forces = vec![0.0; n3 * k];
        for ((zc, yc), f) in z
            .chunks_exact(n4)
            .zip(y.chunks_exact_mut(n4))
            .zip(forces.chunks_exact_mut(n3))
        {
            self.local(w, zc, f, yc)?;
        }
        fn dense<'b>(op: StepOperator<'b>) -> Option<&'b [f64]> {
            match op {
                StepOperator::Dense(m) => Some(m),
                StepOperator::Kernel(_) => None,
            }
        }
        let s = dense(self.s_op).expect("dense storage");
        let d = self.d_op.and_then(dense);
        match self.storage {
            OperatorStorage::Grid => {
                let nc = self.sht.n_coefs();
                let gemm = |op: MatRef<'_, f64>, rhs: MatRef<'_, f64>, y: &mut [f64], beta: f64| {
                    matmul(
                        MatMut::from_column_major_slice_with_stride_mut(y, n3, k, n4),
                        Accum::Add,
                        op,
                        rhs,
                        beta,
                        Par::Seq,
                    );
                };
                if s.len() == n3 * 3 * nc {
                    // The rows over coefficients (the upsampled default): A x = P (F x).
                    let ws = &mut w.products.ws;
                    fn rows(op: &[f64], n3: usize, nc3: usize) -> MatRef<'_, f64> {
                        MatRef::from_row_major_slice(op, n3, nc3)
                    }
                    let mut fc = vec![0.0; 3 * nc * k];
                    self.sht.forward(&forces, &mut fc, ws)?;
                    gemm(
                        rows(s, n3, 3 * nc),
                        MatRef::from_column_major_slice(&fc, 3 * nc, k),
                        y,
                        -self.tau,
                    );
                    if let Some(d) = d {
                        // F X of every column: the first three of its four fields.
                        let mut xc = vec![0.0; 4 * nc * k];
                        self.sht.forward(z, &mut xc, ws)?;
                        let xm =
                            MatRef::from_column_major_slice_with_stride(&xc, 3 * nc, k, 4 * nc);
                        gemm(rows(d, n3, 3 * nc), xm, y, -self.c_d);
                    }
                } else {
                    let fm = MatRef::from_column_major_slice(&forces, n3, k);
                    gemm(MatRef::from_column_major_slice(s, n3, n3), fm, y, -self.tau);
                    if let Some(d) = d {
                        let xm = MatRef::from_column_major_slice_with_stride(z, n3, k, n4);
                        gemm(MatRef::from_column_major_slice(d, n3, n3), xm, y, -self.c_d);
                    }
                }
            }
            OperatorStorage::Coefficients => {
                let nc = self.sht.n_coefs();
                let ws = &mut w.products.ws;
                let mut fc = vec![0.0; 3 * nc * k];
                self.sht.forward(&forces, &mut fc, ws)?;
                let mut yc = vec![0.0; 3 * nc * k];
                let gemm = |op: &[f64], rhs: MatRef<'_, f64>, yc: &mut [f64], beta: f64| {
                    matmul(
                        MatMut::from_column_major_slice_mut(yc, 3 * nc, k),
                        Accum::Add,
                        MatRef::from_column_major_slice(op, 3 * nc, 3 * nc),
                        rhs,
                        beta,
                        Par::Seq,
                    );
                };
                gemm(
                    s,
                    MatRef::from_column_major_slice(&fc, 3 * nc, k),
                    &mut yc,
                    -self.tau,
                );
                if let Some(d) = d {
                    // F X of every column: the first three of its four fields.
                    let mut xc = vec![0.0; 4 * nc * k];
                    self.sht.forward(z, &mut xc, ws)?;
                    let xm = MatRef::from_column_major_slice_with_stride(&xc, 3 * nc, k, 4 * nc);
                    gemm(d, xm, &mut yc, -self.c_d);
                }
                self.sht.inverse(&yc, &mut forces, ws)?;
                for (yc, g) in y.chunks_exact_mut(n4).zip(forces.chunks_exact(n3)) {
                    for (a, b) in yc[..n3].iter_mut().zip(g) {
                        *a += b;
                    }
                }
            }
            OperatorStorage::MatrixFree => unreachable!("dense storage only"),
        }
        Ok(())
    }
}

impl InextensibleOperator<'_> {
    /// `S f` and, with `g`, `D g` at the grid points, with this step's stored dense layers at
    /// its geometry `X*` (the near zones' on-surface values,
    /// [`super::near_pairs::OnSurface`]); `None` where a layer this asks for is applied
    /// matrix-free (the near zones' evaluator then computes them).
    pub fn layer_values(&self, f: &[f64], g: Option<&[f64]>) -> Result<LayerValues, VesicleError> {
        let dense = |op: &StepOperator<'_>| matches!(op, StepOperator::Dense(_));
        let stored = matches!(
            self.storage,
            OperatorStorage::Grid | OperatorStorage::Coefficients
        );
        if !stored || !dense(&self.s_op) || (g.is_some() && !self.d_op.as_ref().is_some_and(dense))
        {
            return Ok(None);
        }
        let n3 = 3 * self.n;
        let mut guard = self.work.lock().unwrap_or_else(|e| e.into_inner());
        let w = &mut *guard;
        let mut product = |op: StepOperator<'_>, x: &[f64]| {
            let mut y = vec![0.0; n3];
            apply_operators(
                self.storage,
                self.sht,
                &mut w.products,
                self.xstar,
                (op, x, 1.0),
                None,
                &mut y,
            )
            .map(|_| y)
        };
        let single = product(self.s_op, f)?;
        let double = match (g, self.d_op) {
            (Some(g), Some(d)) => Some(product(d, g)?),
            _ => None,
        };
        Ok(Some((single, double)))
    }

    /// `y ← A z` and `f ← B X + T σ (+ J X)`, the traction of `z` that the product passes
    /// through the single layer (the density the near-implicit coupling passes to the other
    /// cells, [`super::near_implicit`]). A failure writes NaN into both and is kept.
    pub fn apply_with_traction(&self, z: &[f64], y: &mut [f64], f: &mut [f64]) {
        match self.apply_one(z, y) {
            Ok(()) => {
                let w = self.work.lock().unwrap_or_else(|e| e.into_inner());
                f.copy_from_slice(&w.fb);
            }
            Err(e) => {
                self.fail(e);
                y.fill(f64::NAN);
                f.fill(f64::NAN);
            }
        }
    }
}

impl LinearOperator for InextensibleOperator<'_> {
    fn nrows(&self) -> usize {
        4 * self.n
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        if let Err(e) = self.apply_one(x, y) {
            self.fail(e);
            y.fill(f64::NAN);
        }
    }

    fn apply_batch(&self, x: &[f64], y: &mut [f64], k: usize) {
        let dense = matches!(self.s_op, StepOperator::Dense(_))
            && matches!(
                self.storage,
                OperatorStorage::Grid | OperatorStorage::Coefficients
            );
        let n4 = 4 * self.n;
        if !dense || x.len() != k * n4 || y.len() != k * n4 {
            for (xc, yc) in x.chunks_exact(n4).zip(y.chunks_exact_mut(n4)).take(k) {
                self.apply(xc, yc);
            }
            return;
        }
        if let Err(e) = self.apply_dense_batch(x, y, k) {
            self.fail(e);
            y.fill(f64::NAN);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::timestep::step_engine::EnginePool;
    use crate::timestep::step_solve::assemble_operator;
    use crate::vesicle::layer::{RotationAlgorithm, SelfInteraction};
    use crate::vesicle::shapes::ellipsoid;

    /// The layers a step's operator hands the near zones (`S f`, `D g` with its stored dense
    /// operators, in either storage) are the singular quadrature's values at the grid points,
    /// computed matrix-free by an independent `SelfInteraction` of the same orders; matrix-free
    /// storage hands none.
    #[test]
    fn layer_values_are_the_self_interaction_at_the_grid_points() {
        let (p, q) = (6, 12);
        let surface = ellipsoid(p, [1.3, 1.0, 0.7]).unwrap();
        let coefs = surface.coefs().to_vec();
        let pool = EnginePool::shared(p, q, 20);
        let mut engine = pool.lease().unwrap();
        let n = engine.sht.n_points();
        // Smooth densities (low-degree polynomials of the position).
        let x = surface.grid_positions(&engine.sht).unwrap();
        let f: Vec<f64> = (0..3 * n)
            .map(|i| {
                let k = i % n;
                1.0 + 0.5 * x[k] * x[n + k] - (i / n) as f64 * x[2 * n + k]
            })
            .collect();
        let g: Vec<f64> = (0..3 * n)
            .map(|i| {
                let k = i % n;
                0.3 * x[n + k] + (i / n) as f64 * x[k] * x[k]
            })
            .collect();
        let single = LayerKernel::SingleLayer { viscosity: 1.7 };
        let mut own = SelfInteraction::new(p, q, RotationAlgorithm::ViaSh).unwrap();
        let (mut sf, mut dg) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
        own.evaluate(single, &coefs, &f, &mut sf).unwrap();
        own.evaluate(LayerKernel::DoubleLayer, &coefs, &g, &mut dg)
            .unwrap();
        let scale = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for storage in [OperatorStorage::Grid, OperatorStorage::Coefficients] {
            let (mut s, mut d) = (Vec::new(), Vec::new());
            assemble_operator(&mut engine, storage, single, &coefs, &mut s).unwrap();
            let dl = LayerKernel::DoubleLayer;
            assemble_operator(&mut engine, storage, dl, &coefs, &mut d).unwrap();
            let op = InextensibleOperator::new(
                n,
                &engine.work,
                &engine.sht,
                storage,
                &coefs,
                (StepOperator::Dense(&s), Some(StepOperator::Dense(&d))),
                [3.0, -4.0, 0.01, 0.1],
                None,
                1.0,
            );
            let (s_f, d_g) = op.layer_values(&f, Some(&g)).unwrap().unwrap();
            let d_g = d_g.unwrap();
            // Coefficient storage returns the band-limited part (degrees <= p) of the values.
            let band = |v: &[f64]| {
                let mut ws = engine.sht.workspace();
                let mut c = vec![0.0; 3 * engine.sht.n_coefs()];
                let mut out = vec![0.0; 3 * n];
                engine.sht.forward(v, &mut c, &mut ws).unwrap();
                engine.sht.inverse(&c, &mut out, &mut ws).unwrap();
                out
            };
            let (sf_want, dg_want) = match storage {
                OperatorStorage::Coefficients => (band(&sf), band(&dg)),
                _ => (sf.clone(), dg.clone()),
            };
            for (got, want) in [(&s_f, &sf_want), (&d_g, &dg_want)] {
                let err = got
                    .iter()
                    .zip(want.iter())
                    .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                assert!(
                    err <= 1e-11 * scale(want),
                    "{storage:?}: {err:.3e} of {:.3e}",
                    scale(want)
                );
            }
            let alone = op.layer_values(&f, None).unwrap().unwrap();
            assert!(alone.1.is_none() && alone.0 == s_f);
        }
        let free = InextensibleOperator::new(
            n,
            &engine.work,
            &engine.sht,
            OperatorStorage::MatrixFree,
            &coefs,
            (StepOperator::Kernel(single), None),
            [1.0, 0.0, 0.01, 0.1],
            None,
            1.0,
        );
        assert!(free.layer_values(&f, None).unwrap().is_none());
    }
}
