//! A rigid move of a cell with its whole state: what the contact projection and the recycling
//! of a tube apply.
//!
//! A rigid move `x ↦ R (x − c) + c + t` carries the surface `Xⁿ` and the surface before it
//! `Xⁿ⁻¹` (so that BDF2's extrapolation `2Xⁿ − Xⁿ⁻¹` and its derivative see the same rigid
//! motion and no spurious velocity), and turns every vector the cell keeps on its grid by `R`:
//! the membrane velocity, the velocities induced by the other cells at this step and the one
//! before, and the traction and double-layer density the near-implicit coupling extrapolates.
//! Scalars on the grid (the tension) and the Skalak reference (the elastic energy is the same
//! for a turned membrane) are unchanged.

use super::super::cell_state::CellState;
use super::super::contact::Move;

/// Move `state` by `m`: its surfaces' modes, and the vectors it keeps on its grid (component
/// blocks of `n` points) turned by `m`'s rotation. The cell's own preconditioner is kept: the
/// step turns it with the grid ([`super::super::grid_frame`]).
pub(super) fn move_state(state: &mut CellState, m: &Move) {
    m.apply(&mut state.coefs);
    if let Some(prev) = &mut state.previous_coefs {
        m.apply(prev);
    }
    if !m.turns() {
        return;
    }
    let turn = |v: &mut [f64]| {
        let n = v.len() / 3;
        for j in 0..n {
            let x = [v[j], v[n + j], v[2 * n + j]];
            for (a, row) in m.rotation.iter().enumerate() {
                v[a * n + j] = crate::linalg3::dot3(*row, x);
            }
        }
    };
    for v in [
        &mut state.membrane_velocity,
        &mut state.velocity,
        &mut state.previous_velocity,
    ]
    .into_iter()
    .flatten()
    {
        turn(v);
    }
    if let Some(d) = &mut state.previous_density {
        let half = d.len() / 2;
        let (f, g) = d.split_at_mut(half);
        turn(f);
        turn(g);
    }
}
