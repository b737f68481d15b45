//! The semi-implicit step of one vesicle (Veerapaneni, Rahimian, Biros & Zorin, *A fast
//! algorithm for simulating vesicle flows in three dimensions*, J. Comput. Phys. 230 (2011)
//! 5610), first order (Euler) or second order (BDF2 with extrapolated operators), any viscosity
//! ratio `λ = μ_in/μ_out`, in a background flow with a body force.
//!
//! This module holds the scheme (below) and its parameters ([`VesicleParams`],
//! [`TimeScheme`], [`Preconditioning`], [`ExplicitTerms`], [`StepReport`]). A cell's state is
//! [`super::cell_state::CellState`]; [`super::cell_stepper::CellStepper`] steps it, in the
//! named phases of [`super::step_phases`] with the linear solve of [`super::step_solve`];
//! [`super::vesicle_stepper::VesicleStepper`] is one cell with its state, for single-cell
//! studies.
//!
//! ## The boundary integral equation
//!
//! On the membrane the velocity `u = dX/dt` satisfies (design 3.3; Pozrikidis 1992)
//!
//! ```text
//!     ((1+λ)/2) u − (1−λ) D[u] = u_∞ + S[f],      f = f_b(X) + f_σ(σ) + f_ext,
//!     ∇ₛ·u = 0                                    (local inextensibility),
//! ```
//!
//! with `S` the single layer of the outer viscosity `μ`, `D` the double layer (principal value,
//! `D[c] = −c/2` for a constant `c`, see [`crate::vesicle::layer`]), `f_b` the bending and
//! `f_σ = ∇ₛσ + 2σH n` the tension force. A rigid translation `u = U` gives `D[U] = −U/2` and
//! `U = u_∞ + S[f]` whatever `λ`. `D` is assembled only when `λ ≠ 1`.
//!
//! ## Euler (first order)
//!
//! With every operator frozen at `Xⁿ` (`S`, `D`, the linearised bending `B`, tension `T`,
//! surface divergence `Div`) and `u = (X − Xⁿ)/Δt`:
//!
//! ```text
//!     a (X − Xⁿ) − (1−λ) D (X − Xⁿ) − Δt S (B X + T σ) = Δt (u_∞(Xⁿ) + S f_ext)
//!     Div X = Div Xⁿ                                           (∇ₛⁿ·(X − Xⁿ) = 0)
//! ```
//!
//! (`a = (1+λ)/2`), a nonsymmetric system in `4n` unknowns (`n = 2p(p+1)` grid points) solved
//! by GMRES. `S` (and `D`) are assembled once per step as dense self-interaction operators and
//! applied as GEMVs in every iteration; `B X` and `T σ` are applied matrix-free on the upsampled
//! grid. Bending is implicit, so `Δt` is not bound by the explicit stiffness limit
//! `Δt ~ μ h³/κ`.
//!
//! ## BDF2 (second order)
//!
//! Veerapaneni et al. (2011; the 2D scheme of Veerapaneni, Gueyffier, Zorin & Biros,
//! J. Comput. Phys. 228 (2009) 2334): `u ≈ (3Xⁿ⁺¹ − 4Xⁿ + Xⁿ⁻¹)/(2Δt)`, every operator and
//! explicit term frozen at the extrapolated geometry `X* = 2Xⁿ − Xⁿ⁻¹`, and the constraint
//! `∇ₛ*·(3Xⁿ⁺¹ − 4Xⁿ + Xⁿ⁻¹) = 0`. With `X̂ = (4Xⁿ − Xⁿ⁻¹)/3` and `τ = 2Δt/3` this is the
//! Euler system with `Xⁿ → X̂`, `Δt → τ` and the operators of `X*`:
//!
//! ```text
//!     a (X − X̂) − (1−λ) D* (X − X̂) − τ S* (B* X + T* σ) = τ (u_∞(X*) + S* f_ext(X*))
//!     Div* X = Div* X̂
//! ```
//!
//! The first step (no `Xⁿ⁻¹`) is Euler. The stepper keeps `Xⁿ⁻¹`
//! ([`super::cell_state::CellState::previous_coefs`], carried by checkpoints for restarts).
//! Explicit velocities passed by the caller ([`ExplicitTerms`]) are taken as they are (the
//! caller extrapolates them for second order). The area/volume drift correction keeps the
//! order (tests/timestep_order.rs: 1.98, 2.00, 2.01). Reparametrisation moves the grid of `Xⁿ⁺¹`
//! tangentially; the history `Xⁿ` is relabelled by the same parameter map, so that
//! `Xⁿ⁺¹ − Xⁿ` stays the flow's (without this, BDF2 falls to order ≈ 0.9). The
//! reparametrisation itself changes the shape slightly per call, independently of `Δt`, which
//! caps the accuracy at small `Δt` (measured orders 1.94, 1.75, 1.40 over Δt = 0.05 … 0.00625).
//!
//! The membrane velocity of the solve, `u = (Xⁿ⁺¹ − X̂)/τ` on the grid (before the
//! reparametrisation and the drift correction), is kept ([`super::cell_state::CellState::membrane_velocity`]): a
//! suspension passes `(1 − λ) u` to the other cells as the density of this cell's double layer
//! (explicitly, in the next step).
//!
//! ## Capsules
//!
//! Without the inextensibility constraint ([`VesicleParams::inextensible`] `= false`) the
//! membrane resists through its hyperelastic law `f_e(X)` ([`crate::vesicle::skalak`]) and the
//! tension disappears. The elastic force is linearised about the operators' geometry,
//! `f_e(X) ≈ f_e(X*) + J (X − X*)` (linearly implicit, "implicit where it pays": the explicit
//! limit `Δt ~ μ a / (G_s p)` falls with the order), and with `δ = X − X*` the step is
//!
//! ```text
//!     a δ − (1−λ) D δ − τ S (B + J) δ = a (X̂ − X*) − (1−λ) D (X̂ − X*)
//!                                        + τ (u_∞(X*) + S (f_e(X*) + B X* + f_ext))
//! ```
//!
//! in `3n` unknowns. `J δ` is the directional derivative of the elastic force, taken by a
//! central difference `(f_e(X* + εδ) − f_e(X* − εδ))/2ε` with `ε|δ|` a `10⁻⁵` fraction of the
//! cell's size (relative error `~10⁻¹⁰`, which multiplies the small `δ = O(Δt)`, not the
//! surface; a one-sided difference left GMRES at a `10⁻⁹` floor at small `Ca`).
//! [`VesicleParams::elastic_stepping`] `= Some(Explicit)` drops `J` (forward Euler in the
//! elasticity; the reference whose stability limit this removes). The area is not a constraint:
//! the step's error estimate is the change of volume alone, and the drift correction (if asked)
//! restores the volume only, by a uniform normal displacement.
//!
//! An inextensible cell with shear elasticity (an RBC) may take the same linearisation
//! (`elastic_stepping = Some(LinearlyImplicit)`; its default is explicit, the tension carrying
//! most of the in-plane load): its `4n` system is then solved for `[δ; σ]`, the right-hand side
//! shifted by the operator (without `J`) applied to `[X*; 0]`, and `−τ S J δ` added to every
//! product. The sphere preconditioner does not see `J`, so the iterations grow with `G_s Δt`.
//!
//! ## Preconditioner
//!
//! With [`VesicleParams::preconditioner`] GMRES is right-preconditioned by the inverse step
//! operator of the sphere of the cell's area-equivalent radius `R = √(A/4π)`
//! ([`super::sphere_preconditioner`]), built once and rebuilt only when `R` drifts by more than
//! 1% or `τ`, `κ`, `μ`, `λ` change (the two `τ` of a BDF2 run are both kept). The sphere's
//! grid point `ξ` has the normal `ξ`; a cell's grid, carried by tank-treading or tumbling, turns
//! away from that, so at every step the preconditioner is turned by the rotation that best maps
//! the grid directions onto the cell's normals ([`super::grid_frame`]). Without this the
//! iterations per step grow with the angle the grid has turned, until a step fails (one
//! vesicle of reduced volume 0.85 in shear at p = 12: 19 → 326 iterations per step from t = 0.4
//! to t = 6, then no convergence; turned: 16–19 for t ≤ 40).
//!
//! The sphere's error grows with the cell's distance from the sphere (p = 12: 9 iterations per
//! step for a sphere, 18 for a prolate of reduced volume 0.85, 22 for an RBC, and more with
//! `p`). [`Preconditioning::Cell`] ([`super::cell_stepper::CellStepper::set_preconditioning`], scene
//! `[numerics] preconditioner = "cell"`) uses the exact inverse of the cell's own step
//! operator instead ([`super::cell_preconditioner`]): built at a step from that step's operator
//! (GMRES then takes at most two iterations), turned with the grid at later steps like the
//! sphere's (by the rotation from the grid's frame at the build to the current one), and rebuilt
//! when a step takes more than `rebuild_after` iterations or `τ` changes by more than 10 %
//! (an adaptive `Δt`, BDF2 after its first step). It is rebuilt bit for
//! bit from its [`super::cell_state::PreconditionerRecord`] (the surface, `τ` and Skalak reference it was built
//! from), which travels with the cell's state, so runs with it resume and migrate exactly.
//! Not with matrix-free operators (the build would apply them `4n_c` times): those keep the
//! sphere's.
//!
//! ## Local area
//!
//! The linearised constraint `Div (X − X̂) = 0` keeps each material point's area element `W`
//! only to first order, and over many steps `W` drifts from its start. A vesicle does not
//! notice, but with shear elasticity and a large area-dilation ratio `C` the drift is an area
//! strain `J = W/W_ref ≠ 1` whose Skalak stress `~ G_s C (J² − 1)` the tension must balance.
//! (An RBC with Skalak, `G_s = 0.2`, `C = 10`, in shear at p = 12: the largest `|J − 1|` grew
//! 0.07 → 0.5 → 2.0 over t = 2, 56, 74, with the reference itself drifting, until GMRES
//! stagnated at t = 76; docs/long_runs_cause.md.) For an inextensible cell with a Skalak
//! reference the constraint therefore carries the source
//!
//! ```text
//!     Div (X − X̂) = min(k Δt, 1) (τ/Δt) (W_ref (A/A_ref) / Wⁿ − 1)
//! ```
//!
//! (filtered as `Div` is, so that it lies in its range), which brings `W` back toward the
//! reference's area element at the same material point (the reference moves with the grid, so
//! that `W_ref` is at the same point), scaled to the area `A` the drift correction restores: at
//! the rate `k` per unit time ([`super::cell_stepper::CellStepper::set_local_area_rate`],
//! default 10; `mobo run` multiplies it by the scene's fastest rate), or the whole gap in one
//! step for Euler when `k Δt ≥ 1` (`Wⁿ⁺¹ ≈ Wⁿ (1 + Div (X − Xⁿ))`). Why a rate and not the
//! whole gap: the relaxation and the drift correction pull toward targets that differ by the
//! discretisation's error, so closing the whole gap every step moves the surface by an amount
//! that does not shrink with `Δt` (at p = 8, about 1.5e-6 a step), and the error of a run then
//! grows with the number of steps: one RBC at p = 8 in shear had a floor of about 2e-4 in its
//! shape error whatever `Δt`; at the rate 10 it is second order (2.03, 2.09, 2.35 from
//! `Δt = 0.04` to 0.005; docs/long_runs_cause.md). For BDF2 the constraint is linearised
//! about `X̂`, `Wⁿ⁺¹ ≈ Ŵ (1 + Div (X − X̂))`, and this source closes the share `τ/Δt` (2/3 at a
//! constant step) of that share per step; the error of the gap then obeys a two-step recursion
//! that is stable for step ratios `ω ≲ 2.4`, above the adaptive controller's bound `√2`. (The
//! one-step form `W_ref/Ŵ − 1` was tried: it broke the second order of BDF2 measured by
//! tests/capsule.rs, the difference of the explicit and the implicit elasticity rising from
//! 7.8e-6 at Δt = 0.001 to 1.5e-5 at 0.0005.) A correction toward the constraint's manifold,
//! zero when `W = W_ref` and, at a finite rate, `O(Δt)` times the gap per step otherwise, so
//! the step keeps its order.
//! [`super::cell_stepper::CellStepper::set_local_area_relaxation`] switches it off.
//!
//! ## After the step
//!
//! Optionally the grid is reparametrised (tank-treading carries grid points along the membrane
//! and degrades the parametrisation; without it long runs at large `Δt` degenerate). The grid
//! points then move along the surface, and everything the cell keeps per membrane point moves
//! with them (relabelled by the same parameter map): the Skalak reference (otherwise the move
//! reads as a strain), the tension, the membrane velocity, the coupling velocity `vⁿ` (the next
//! step's `vⁿ⁻¹`) and the BDF2 history `Xⁿ⁻¹`. The
//! reference moves through its material labels and is composed afresh from its first surface
//! ([`crate::vesicle::material_labels`]): relabelled itself, its re-fits at every move added up
//! to a change of its shape. The
//! linearised constraint keeps the area only approximately; with `correct_drift` each step ends
//! with a normal displacement `(α + β H) n` whose `α, β` restore the area and volume of the first
//! step (Newton on `δV = ∫ φ dA`, `δA = −2 ∫ H φ dA` for `φ = α + β H`).

pub use super::operator_storage::OperatorStorage;

use super::TimestepError;
use super::{GmresParams, GmresReport};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
use crate::vesicle::membrane::Membrane;
use crate::vesicle::reparam::ReparamParams;

/// Time discretisation of the step (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TimeScheme {
    /// First-order semi-implicit Euler, operators at `Xⁿ`.
    #[default]
    Euler,
    /// Second-order BDF2, operators at `X* = 2Xⁿ − Xⁿ⁻¹`; the first step is Euler.
    Bdf2,
}

/// How the membrane's elastic force (Skalak or neo-Hookean) enters the step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ElasticStepping {
    /// Evaluated at the operators' geometry `X*` (`Xⁿ` for Euler, the extrapolation for BDF2;
    /// stable only below `Δt ~ μa/(G_s p)`).
    Explicit,
    /// Linearised about `X*`: `f_e(X) ≈ f_e(X*) + J (X − X*)`, the Jacobian applied in every
    /// GMRES iteration by a central difference ("Capsules" in the module docs).
    LinearlyImplicit,
}

/// Which preconditioner GMRES uses for an inextensible cell (with
/// [`VesicleParams::preconditioner`] on; see "Preconditioner" in the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Preconditioning {
    /// The inverse step operator of the sphere of the cell's area, turned with the grid
    /// ([`super::sphere_preconditioner`]): built once, cheap to keep, its error grows with the
    /// cell's distance from the sphere.
    #[default]
    Sphere,
    /// The inverse of the cell's own step operator ([`super::cell_preconditioner`]), built at a
    /// step, turned with the grid at later steps, and rebuilt by the step after one of more
    /// than `rebuild_after` GMRES iterations (or by a step whose `τ` differs by more than 10 %,
    /// or whose other coefficients differ). A cell too close to a sphere to invert its own
    /// operator uses the sphere's.
    Cell {
        /// Iterations of a step above which the next step rebuilds the preconditioner.
        rebuild_after: usize,
    },
}

impl Preconditioning {
    /// The default of [`Preconditioning::Cell`]'s `rebuild_after`.
    pub const DEFAULT_REBUILD_AFTER: usize = 8;
    /// The cell's own operator, rebuilt after a step of more than 8 iterations.
    pub const CELL: Preconditioning = Preconditioning::Cell {
        rebuild_after: Self::DEFAULT_REBUILD_AFTER,
    };
}

/// Physical and numerical parameters of a vesicle step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VesicleParams {
    /// Bending modulus `κ_b`.
    pub bending_modulus: f64,
    /// Viscosity `μ` of the outer fluid (`μ_out`; the inner one is `λ μ`).
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
    /// Right-precondition GMRES by the inverse step operator of the area-equivalent sphere
    /// ([`super::sphere_preconditioner`]). Inextensible cells only: a capsule's system has no
    /// tension block, and it is solved unpreconditioned whatever this says.
    pub preconditioner: bool,
    /// Euler or BDF2.
    pub scheme: TimeScheme,
    /// Viscosity ratio `λ = μ_in / μ_out` (positive; 1: no double layer).
    pub viscosity_ratio: f64,
    /// `true`: a vesicle or RBC, locally inextensible (`∇ₛ·u = 0`, with the tension as
    /// unknown). `false`: a capsule, whose membrane stretches and resists through its elastic law
    /// alone ([`super::cell_stepper::CellStepper::set_skalak`], required); see "Capsules" in the module docs.
    pub inextensible: bool,
    /// How the elastic force enters the step (`None`: linearly implicit for a capsule,
    /// explicit for an inextensible cell, whose tension carries most of the in-plane load).
    pub elastic_stepping: Option<ElasticStepping>,
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

/// BDF2's extrapolation of a quantity to the next step, `(1 + ω) now − ω previous`
/// (`ω = Δtⁿ/Δtⁿ⁻¹`; `2 now − previous` at a constant step), or `now` itself without a previous
/// value or without `ω` (Euler, a first step).
pub(crate) fn extrapolate(now: &[f64], previous: Option<&[f64]>, omega: Option<f64>) -> Vec<f64> {
    match (previous, omega) {
        (Some(p), Some(w)) => now
            .iter()
            .zip(p)
            .map(|(a, b)| (1.0 + w) * a - w * b)
            .collect(),
        _ => now.to_vec(),
    }
}

/// What one step did.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// The GMRES solve.
    pub gmres: GmresReport,
    /// The scheme of this step (the first step of a BDF2 run is Euler).
    pub scheme: TimeScheme,
    /// Whether a preconditioner (the sphere's or the cell's own) was (re)built in this step.
    pub preconditioner_built: bool,
    /// The step's area/volume error, `max(|Aⁿ⁺¹ − Aⁿ|/Aⁿ, |Vⁿ⁺¹ − Vⁿ|/Vⁿ)` measured before the
    /// drift correction: the exact flow keeps both, so this is an error estimate of the step
    /// (what [`super::adaptive`] controls).
    pub area_volume_error: f64,
}

/// Error unless `v` is positive and finite (a parameter named `name`).
pub(crate) fn check(name: &'static str, v: f64) -> Result<(), TimestepError> {
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
