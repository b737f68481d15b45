//! The first-order semi-implicit step of one vesicle (Veerapaneni, Rahimian, Biros & Zorin,
//! J. Comput. Phys. 230, 2011), viscosity ratio 1, in a background flow with a body force.
//!
//! With the geometry frozen at `Xⁿ` (single layer `S`, linearised bending `B`, tension `T`,
//! surface divergence `Div`, all of `Xⁿ`), the new positions and tension solve
//!
//! ```text
//!     X − Δt S (B X + T σ) = Xⁿ + Δt (u_∞(Xⁿ) + S f_ext)
//!     Div X                = Div Xⁿ              (∇ₛⁿ·(X − Xⁿ) = 0, inextensibility)
//! ```
//!
//! a nonsymmetric system in `4n` unknowns (`n = 2p(p+1)` grid points) solved by GMRES. `S` is
//! assembled once per step as the dense self-interaction operator and applied as a GEMV in
//! every iteration; `B X` and `T σ` are applied matrix-free on the upsampled grid. Bending is
//! implicit, so `Δt` is not bound by the explicit stiffness limit `Δt ~ μ h³/κ`.
//!
//! Optionally the grid is reparametrised after each step (tank-treading carries grid points
//! along the membrane and degrades the parametrisation; without it long runs at large `Δt`
//! degenerate). The linearised constraint keeps the area to first order only; with `correct_drift` each
//! step ends with a normal displacement `(α + β H) n` whose `α, β` restore the area and volume
//! of the first step (Newton on `δV = ∫ φ dA`, `δA = −2 ∫ H φ dA` for `φ = α + β H`).

use std::sync::Mutex;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::TimestepError;
use super::{gmres, FnOperator, GmresParams, GmresReport, GmresWorkspace, Identity};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
use crate::vesicle::membrane::Membrane;
use crate::vesicle::reparam::{reparametrize, ReparamParams};
use crate::vesicle::shapes::Surface;
use crate::vesicle::skalak::SkalakParams;

/// Physical and numerical parameters of a vesicle step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VesicleParams {
    /// Bending modulus `κ_b`.
    pub bending_modulus: f64,
    /// Viscosity `μ` (inside and outside).
    pub viscosity: f64,
    /// Body force on the cell (spread as a uniform traction `F / A`).
    pub force: [f64; 3],
    /// Time step.
    pub dt: f64,
    /// Quadrature order of the forces and the singular integrals (`q ≥ p`, usually `2p`).
    pub upsampled_order: usize,
    /// Linear solver settings.
    pub gmres: GmresParams,
    /// Restore the initial area and volume after every step.
    pub correct_drift: bool,
    /// Reparametrise the grid after every step (remove tangential drift; Veerapaneni et al.
    /// 2011 §3.4), before the drift correction.
    pub reparametrize: Option<ReparamParams>,
}

/// Explicit terms of one step (other cells, elastic forces computed at `Xⁿ`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ExplicitTerms<'a> {
    /// A velocity on the order-`p` grid (`3n`, component-major) added to `u_∞(Xⁿ)`: the
    /// velocity induced by the other cells.
    pub velocity: Option<&'a [f64]>,
    /// A traction on the order-`p` grid (`3n`) added to the body-force traction and applied
    /// through the cell's own single layer (e.g. a contact repulsion).
    pub traction: Option<&'a [f64]>,
}

/// What one step did.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// The GMRES solve.
    pub gmres: GmresReport,
}

/// What one application of the step operator needs, reused across GMRES iterations.
struct OperatorWork {
    membrane: Membrane,
    /// Bending and tension forces (`3n` each).
    fb: Vec<f64>,
    ft: Vec<f64>,
}

/// Steps one vesicle of SH order `p`.
pub struct VesicleStepper {
    p: usize,
    params: VesicleParams,
    /// The membrane engine and the force scratch of the operator (locked while applied).
    work: Mutex<OperatorWork>,
    layer: SelfInteraction,
    sht: ShTransform,
    ws: ShWorkspace,
    /// Dense single layer, `3n × 3n`, column-major.
    s_op: Vec<f64>,
    /// Tension of the last step (initial guess of the next).
    pub sigma: Vec<f64>,
    gmres_ws: GmresWorkspace,
    calc: SurfaceCalculus,
    /// Area and volume to restore (those of the first step's surface).
    targets: Option<(f64, f64)>,
    /// Shear elasticity (explicit, relative to the reference set by [`VesicleStepper::set_skalak`]).
    skalak: Option<SkalakParams>,
}

fn check(name: &'static str, v: f64) -> Result<(), TimestepError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(TimestepError::InvalidParameter {
            name,
            value: format!("{v}"),
            reason: "must be positive and finite",
        })
    }
}

impl VesicleStepper {
    /// Plans for order `p`.
    pub fn new(p: usize, params: VesicleParams) -> Result<Self, TimestepError> {
        check("bending_modulus", params.bending_modulus)?;
        check("viscosity", params.viscosity)?;
        check("dt", params.dt)?;
        if !params.force.iter().all(|f| f.is_finite()) {
            return Err(TimestepError::NonFinite { what: "force" });
        }
        params.gmres.validate()?;
        let q = params.upsampled_order.max(p);
        let sht = ShTransform::new(p).map_err(crate::vesicle::VesicleError::from)?;
        let ws = sht.workspace();
        let n = sht.n_points();
        Ok(VesicleStepper {
            p,
            params,
            work: Mutex::new(OperatorWork {
                membrane: Membrane::new(p, q)?,
                fb: vec![0.0; 3 * n],
                ft: vec![0.0; 3 * n],
            }),
            layer: SelfInteraction::new(p, q, RotationAlgorithm::Direct)?,
            sht,
            ws,
            s_op: vec![0.0; 9 * n * n],
            sigma: vec![0.0; n],
            gmres_ws: GmresWorkspace::new(4 * n, params.gmres.restart),
            calc: SurfaceCalculus::new(p)?,
            targets: None,
            skalak: None,
        })
    }

    /// Add Skalak shear elasticity (explicit in time) relative to the stress-free surface
    /// `reference` (order-`p` coefficients, same parametrisation as the stepped surface).
    pub fn set_skalak(
        &mut self,
        params: SkalakParams,
        reference: &[f64],
    ) -> Result<(), TimestepError> {
        self.work
            .lock()
            .expect("operator lock")
            .membrane
            .set_reference(reference)?;
        self.skalak = Some(params);
        Ok(())
    }

    /// The area and volume the drift correction restores (set at the first step).
    pub fn drift_targets(&self) -> Option<(f64, f64)> {
        self.targets
    }

    /// Set the area and volume the drift correction restores (a restarted run keeps those of
    /// its first step).
    pub fn set_drift_targets(&mut self, targets: Option<(f64, f64)>) {
        self.targets = targets;
    }

    /// Parameters.
    pub fn params(&self) -> &VesicleParams {
        &self.params
    }

    /// The traction the membrane exerts on the fluid at the surface `coefs`, with the tension
    /// of the last step: `f_b(X) + f_σ(σ) + f_Skalak(X) + F/A` on the order-`p` grid (`3n`).
    /// This is the density whose single layer the other cells feel (explicit coupling).
    pub fn traction(&mut self, coefs: &[f64], out: &mut [f64]) -> Result<(), TimestepError> {
        let n = self.sht.n_points();
        if out.len() != 3 * n {
            return Err(TimestepError::DimensionMismatch {
                what: "traction",
                expected: 3 * n,
                got: out.len(),
            });
        }
        let mut guard = self.work.lock().expect("operator lock");
        let OperatorWork { membrane, fb, ft } = &mut *guard;
        membrane.set_geometry(coefs)?;
        let area = membrane.geometry()?.area();
        membrane.bending_force(self.params.bending_modulus, out)?;
        membrane.tension_force(&self.sigma, ft)?;
        for (o, t) in out.iter_mut().zip(ft.iter()) {
            *o += t;
        }
        if let Some(sk) = &self.skalak {
            membrane.skalak_force(sk, fb)?;
            for (o, t) in out.iter_mut().zip(fb.iter()) {
                *o += t;
            }
        }
        for c in 0..3 {
            for o in &mut out[c * n..(c + 1) * n] {
                *o += self.params.force[c] / area;
            }
        }
        Ok(())
    }

    /// SH order.
    pub fn order(&self) -> usize {
        self.p
    }

    /// Grid points per cell, `n = 2p(p+1)`.
    pub fn n_points(&self) -> usize {
        self.sht.n_points()
    }

    /// Advance the surface with coefficients `coefs` (x, y, z at order `p`) by one step in the
    /// background flow `u_inf`.
    pub fn step(
        &mut self,
        coefs: &mut [f64],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    ) -> Result<StepReport, TimestepError> {
        self.step_with(coefs, u_inf, ExplicitTerms::default())
    }

    /// One step with explicit terms (the velocity induced by other cells, extra tractions).
    pub fn step_with(
        &mut self,
        coefs: &mut [f64],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<StepReport, TimestepError> {
        let n = self.sht.n_points();
        for (what, v) in [("velocity", extra.velocity), ("traction", extra.traction)] {
            if let Some(v) = v {
                if v.len() != 3 * n {
                    return Err(TimestepError::DimensionMismatch {
                        what,
                        expected: 3 * n,
                        got: v.len(),
                    });
                }
            }
        }
        let (dt, kappa) = (self.params.dt, self.params.bending_modulus);
        if self.targets.is_none() {
            let g = self.calc.geometry(coefs)?;
            self.targets = Some((g.area(), g.volume()));
        }
        let mut xg = vec![0.0; 3 * n];
        self.sht
            .inverse(coefs, &mut xg, &mut self.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        let mut fext = vec![0.0; 3 * n];
        let area = {
            let mut guard = self.work.lock().expect("operator lock");
            let OperatorWork { membrane, fb, .. } = &mut *guard;
            membrane.set_geometry(coefs)?;
            if let Some(sk) = &self.skalak {
                membrane.skalak_force(sk, fb)?;
                fext.copy_from_slice(fb);
            }
            membrane.geometry()?.area()
        };
        if let Some(t) = extra.traction {
            for (a, b) in fext.iter_mut().zip(t) {
                *a += b;
            }
        }
        self.layer.assemble(
            LayerKernel::SingleLayer {
                viscosity: self.params.viscosity,
            },
            coefs,
            &mut self.s_op,
        )?;
        let s_op = MatRef::from_column_major_slice(&self.s_op, 3 * n, 3 * n);
        let gemv = |x: &[f64], y: &mut [f64], beta: f64| {
            // y ← y + beta · S x
            matmul(
                MatMut::from_column_major_slice_mut(y, 3 * n, 1),
                Accum::Add,
                s_op,
                MatRef::from_column_major_slice(x, 3 * n, 1),
                beta,
                Par::Seq,
            );
        };
        // Right-hand side.
        let mut b = vec![0.0; 4 * n];
        for c in 0..3 {
            for f in &mut fext[c * n..(c + 1) * n] {
                *f += self.params.force[c] / area;
            }
        }
        for j in 0..n {
            let u = u_inf([xg[j], xg[n + j], xg[2 * n + j]]);
            for c in 0..3 {
                let other = extra.velocity.map_or(0.0, |v| v[c * n + j]);
                b[c * n + j] = xg[c * n + j] + dt * (u[c] + other);
            }
        }
        gemv(&fext, &mut b[..3 * n], dt);
        self.work
            .lock()
            .expect("operator lock")
            .membrane
            .surface_divergence(&xg, &mut b[3 * n..])?;
        // The operator [X; σ] ↦ [X − Δt S (B X + T σ); Div X].
        let work = &self.work;
        let failure: Mutex<Option<crate::vesicle::VesicleError>> = Mutex::new(None);
        let op = FnOperator::new(4 * n, |z: &[f64], y: &mut [f64]| {
            let (x, sigma) = z.split_at(3 * n);
            let mut guard = work.lock().expect("operator lock");
            let OperatorWork { membrane, fb, ft } = &mut *guard;
            let r = membrane
                .bending_linear(kappa, x, fb)
                .and_then(|_| membrane.tension_force(sigma, ft))
                .and_then(|_| membrane.surface_divergence(x, &mut y[3 * n..]));
            if let Err(e) = r {
                *failure.lock().expect("failure lock") = Some(e);
                y.fill(f64::NAN);
                return;
            }
            for (a, t) in fb.iter_mut().zip(ft.iter()) {
                *a += t;
            }
            y[..3 * n].copy_from_slice(x);
            gemv(fb, &mut y[..3 * n], -dt);
        });
        let mut z0 = vec![0.0; 4 * n];
        z0[..3 * n].copy_from_slice(&xg);
        z0[3 * n..].copy_from_slice(&self.sigma);
        let mut z = vec![0.0; 4 * n];
        let report = gmres(
            &op,
            &Identity::new(4 * n),
            &b,
            Some(&z0),
            &mut z,
            &self.params.gmres,
            &mut self.gmres_ws,
        );
        if let Some(e) = failure.into_inner().expect("failure lock") {
            return Err(e.into());
        }
        let report = report?;
        self.sigma.copy_from_slice(&z[3 * n..]);
        self.sht
            .forward(&z[..3 * n], coefs, &mut self.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        if let Some(rp) = &self.params.reparametrize {
            let mut surf = Surface::from_coefs(self.p, coefs.to_vec())?;
            reparametrize(&mut surf, rp)?;
            coefs.copy_from_slice(surf.coefs());
        }
        if self.params.correct_drift {
            let (area, volume) = self.targets.expect("set above");
            self.correct_area_volume(coefs, area, volume)?;
        }
        Ok(StepReport { gmres: report })
    }

    /// Move the surface along its normal by `(α + β H) n` so that its area and volume become
    /// `area` and `volume` (three Newton steps; quadratic convergence from a small drift).
    pub fn correct_area_volume(
        &mut self,
        coefs: &mut [f64],
        area: f64,
        volume: f64,
    ) -> Result<(), TimestepError> {
        let n = self.sht.n_points();
        let mut xg = vec![0.0; 3 * n];
        for _ in 0..3 {
            let g = self.calc.geometry(coefs)?;
            let (da, dv) = (area - g.area(), volume - g.volume());
            if da.abs() <= 1e-14 * area && dv.abs() <= 1e-14 * volume {
                break;
            }
            let hh: Vec<f64> = g.h.iter().map(|h| h * h).collect();
            let (i0, i1, i2) = (g.area(), g.integrate(&g.h), g.integrate(&hh));
            // [i0 i1; −2 i1 −2 i2] [α; β] = [δV; δA]
            let det = -2.0 * i0 * i2 + 2.0 * i1 * i1;
            if det.abs() < 1e-300 {
                break;
            }
            let alpha = (-2.0 * i2 * dv - i1 * da) / det;
            let beta = (i0 * da + 2.0 * i1 * dv) / det;
            self.sht
                .inverse(coefs, &mut xg, &mut self.ws)
                .map_err(crate::vesicle::VesicleError::from)?;
            for j in 0..n {
                let phi = alpha + beta * g.h[j];
                for c in 0..3 {
                    xg[c * n + j] += phi * g.normal[j][c];
                }
            }
            self.sht
                .forward(&xg, coefs, &mut self.ws)
                .map_err(crate::vesicle::VesicleError::from)?;
        }
        Ok(())
    }
}

/// Forward Euler of bending-driven flow, `X ← X + Δt (u_∞(X) + S[f_b(X)])`, without the
/// inextensibility constraint: the explicit reference whose stiffness limit `Δt ~ μh³/κ` the
/// semi-implicit step removes (used to measure that limit).
pub struct ExplicitStepper {
    kappa: f64,
    viscosity: f64,
    dt: f64,
    membrane: Membrane,
    layer: SelfInteraction,
    sht: ShTransform,
    ws: ShWorkspace,
    x: Vec<f64>,
    fb: Vec<f64>,
    u: Vec<f64>,
}

impl ExplicitStepper {
    /// Plan for order `p`, forces and quadrature at order `q`.
    pub fn new(
        p: usize,
        q: usize,
        kappa: f64,
        viscosity: f64,
        dt: f64,
    ) -> Result<Self, TimestepError> {
        check("bending_modulus", kappa)?;
        check("viscosity", viscosity)?;
        check("dt", dt)?;
        let sht = ShTransform::new(p).map_err(crate::vesicle::VesicleError::from)?;
        let n = sht.n_points();
        Ok(ExplicitStepper {
            kappa,
            viscosity,
            dt,
            membrane: Membrane::new(p, q)?,
            layer: SelfInteraction::new(p, q, RotationAlgorithm::Direct)?,
            ws: sht.workspace(),
            sht,
            x: vec![0.0; 3 * n],
            fb: vec![0.0; 3 * n],
            u: vec![0.0; 3 * n],
        })
    }

    /// The bending energy `(κ/2)∫(2H)² dA` of a surface.
    pub fn bending_energy(&mut self, coefs: &[f64]) -> Result<f64, TimestepError> {
        self.membrane.set_geometry(coefs)?;
        Ok(self.membrane.bending_energy(self.kappa)?)
    }

    /// One explicit step.
    pub fn step(
        &mut self,
        coefs: &mut [f64],
        u_inf: &dyn Fn([f64; 3]) -> [f64; 3],
    ) -> Result<(), TimestepError> {
        let n = self.sht.n_points();
        self.membrane.set_geometry(coefs)?;
        self.membrane.bending_force(self.kappa, &mut self.fb)?;
        self.layer.evaluate(
            LayerKernel::SingleLayer {
                viscosity: self.viscosity,
            },
            coefs,
            &self.fb,
            &mut self.u,
        )?;
        self.sht
            .inverse(coefs, &mut self.x, &mut self.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        for j in 0..n {
            let b = u_inf([self.x[j], self.x[n + j], self.x[2 * n + j]]);
            for (c, bc) in b.iter().enumerate() {
                self.x[c * n + j] += self.dt * (self.u[c * n + j] + bc);
            }
        }
        self.sht
            .forward(&self.x, coefs, &mut self.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        Ok(())
    }
}

/// Whether forward Euler at step `dt` keeps the bending energy below `growth` times its start
/// for `steps` steps (an error or a non-finite energy counts as divergence).
pub fn explicit_is_stable(
    stepper: &mut ExplicitStepper,
    coefs: &[f64],
    steps: usize,
    growth: f64,
    u_inf: &dyn Fn([f64; 3]) -> [f64; 3],
) -> bool {
    let mut c = coefs.to_vec();
    let Ok(e0) = stepper.bending_energy(&c) else {
        return false;
    };
    for _ in 0..steps {
        if stepper.step(&mut c, u_inf).is_err() {
            return false;
        }
        match stepper.bending_energy(&c) {
            Ok(e) if e.is_finite() && e < growth * e0 => {}
            _ => return false,
        }
    }
    true
}
