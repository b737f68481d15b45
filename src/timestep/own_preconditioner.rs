//! A cell's own preconditioner ([`super::semi_implicit::Preconditioning::Cell`]): what it was
//! built from (its [`super::cell_state::PreconditionerRecord`]) and the inverse.

use super::cell_preconditioner::CellPreconditioner;
use super::cell_state::PreconditionerRecord;
use super::grid_frame::Rotation;
use super::sphere_preconditioner::StepCoefficients;
use super::step_operator::InextensibleOperator;
use super::TimestepError;
use crate::sph_harmonics::ShTransform;

/// A cell's own preconditioner: what it was built from, and the inverse.
pub(super) struct OwnPreconditioner {
    pub(super) record: PreconditionerRecord,
    /// The operator's coefficients (`τ` is the record's; the rest are the stepper's at the
    /// build, compared so that a changed parameter rebuilds it).
    pub(super) coefs: StepCoefficients,
    pub(super) inverse: OwnInverse,
    /// The grid's frame at the build ([`super::grid_frame`]): later steps turn the
    /// preconditioner by how far the grid has turned since.
    pub(super) frame: Rotation,
}

pub(super) enum OwnInverse {
    Built(CellPreconditioner),
    /// The cell was too close to a sphere to invert its own operator: the sphere's
    /// preconditioner serves until this goes stale.
    Singular,
    /// To be rebuilt from the record before its next use (a restored state).
    Pending,
}

/// The inverse of `op` (the step's operator, identity coefficient `a_id`), or `Singular`
/// when the cell is too close to a sphere; a failure of the membrane operators is reported
/// as such.
pub(super) fn own_inverse(
    op: &InextensibleOperator<'_>,
    sht: &ShTransform,
    a_id: f64,
) -> Result<OwnInverse, TimestepError> {
    match CellPreconditioner::build(op, sht, a_id) {
        Ok(pc) => Ok(OwnInverse::Built(pc)),
        Err(TimestepError::SingularBlock { .. }) => Ok(OwnInverse::Singular),
        Err(e) => Err(op.take_failure().map_or(e, TimestepError::from)),
    }
}
