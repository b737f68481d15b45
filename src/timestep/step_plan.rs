//! What a step carries from one of its phases to the next ([`super::step_phases`]): the plan
//! taken from the history, the preconditioners, the explicit terms on the grid.

use super::grid_frame::Rotation;
use super::sphere_preconditioner::StepCoefficients;

use super::semi_implicit::TimeScheme;

/// What a step takes from the history (phase 1 of [`VesicleStepper::step_with`]).
pub(super) struct StepPlan {
    pub(super) scheme: TimeScheme,
    pub(super) tau: f64,
    pub(super) coef: StepCoefficients,
    /// Area and volume of `Xⁿ`.
    pub(super) area0: f64,
    pub(super) volume0: f64,
    /// `X*` (the operators' geometry) and `X̂` (the history term), as coefficients.
    pub(super) xstar: Vec<f64>,
    pub(super) xhat: Vec<f64>,
    /// The local area source of the constraint (`None`: none).
    pub(super) area_source: Option<Vec<f64>>,
    pub(super) inextensible: bool,
    /// Whether the elastic force is linearised in the operator.
    pub(super) implicit_elastic: bool,
    /// Whether GMRES is preconditioned (an inextensible cell with the preconditioner on).
    pub(super) precondition: bool,
}

/// The preconditioners of a step (phase 2).
pub(super) struct StepPreconditioners {
    /// The sphere preconditioner in use (`None`: unpreconditioned), and whether it was built
    /// for this step.
    pub(super) sphere: Option<usize>,
    pub(super) sphere_built: bool,
    /// Whether the cell's own preconditioner is to be built in the solve, and whether it was
    /// rebuilt from its record.
    pub(super) build_own: bool,
    pub(super) own_rebuilt: bool,
    /// How far the grid has turned with the cell.
    pub(super) rotation: Rotation,
}

/// The explicit terms of a step on the order-`p` grid (phase 3).
pub(super) struct GridTerms {
    /// `X*` and `X̂`.
    pub(super) xs_grid: Vec<f64>,
    pub(super) xh_grid: Vec<f64>,
    /// `f_e(X*) + f_extra + F/A`.
    pub(super) traction: Vec<f64>,
    /// `u_∞(X*) + u_other`.
    pub(super) velocity: Vec<f64>,
    /// The area-equivalent radius at `X*`.
    pub(super) size: f64,
}
