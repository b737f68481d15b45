//! What a scene that does not say gets for `[numerics] coupling` and `contact_distance`: the
//! settings that keep a suspension of red cells at blood's viscosity ratio running.
//!
//! * **Coupling** (`coupling = "auto"`, the default). With two or more cells the near cells are
//!   solved as one system ([`CouplingMode::NearImplicit`]); so is a lone cell beside a plane
//!   wall, with its own image (`timestep::near_images`: explicit, the image of a sphere an
//!   eighth of a radius from the plane lags its traction by a step and the sphere's speed
//!   settles over tens of steps); a lone cell elsewhere has nothing to couple
//!   ([`CouplingMode::Explicit`]). The explicit coupling of a neighbour's double layer
//!   `(1 − λ) D[u]` has the gain `|1 − λ|/(1 + λ)` per step on a close pair, tripled on an
//!   alternating mode by BDF2's extrapolation: 27 RBCs at 17 % with `λ = 5` fail at step 35
//!   with it and ran 2000 steps near-implicit (docs/hard_cases.md). Without a contrast it fails
//!   too once the cells are packed: 8 RBCs at 30 % with `λ = 1` (p = 8, BDF2) turn a cell
//!   inside out at step 109 with `Δt = 0.0025` (a smaller step failing, where the near-implicit
//!   coupling runs at every `Δt` from 0.04 down). Where no two cells are within each other's
//!   implicit zone the near-implicit step is the explicit one, so the default costs more only
//!   where the cells are close.
//! * **Contacts** (`contact_distance` absent). With two or more cells, or a cell and a rigid
//!   wall or a plane, the contact projection ([`crate::timestep::contact`]) keeps every surface gap at
//!   least
//!
//!   ```text
//!       d_min = 0.4 · R_min / p
//!   ```
//!
//!   at the end of every step (`R_min` the smallest equivalent radius, `p` the order): `0.05 R`
//!   at p = 8, about an eighth of the grid spacing `πR/p`. Below a small fraction of the grid
//!   spacing the near-singular quadrature of a neighbour loses its accuracy and the coupling of
//!   two close surfaces its stability, whatever the coupling mode (Lu, Rahimian & Zorin,
//!   J. Comput. Phys. 347, 2017: contact constraints "eliminate catastrophic loss of accuracy
//!   for close surfaces"). Measured: 27 RBCs at 17 % with `λ = 10`, p = 8, near-implicit, BDF2,
//!   `Δt = 0.01` and no contacts fail at step 310, three cells of a row pressed to a gap of 0.04
//!   with an alternating mode that Euler does not have; with `d_min = 0.05` the same
//!   checkpoint runs on (docs/hard_cases.md). `contact_distance = 0` turns the projection off.
//!
//! The resolved choices are in the scene's effects (`coupling`, `contacts`), in `summary.json`
//! and in the first lines `mobo run` prints.

use super::cell_scene::{CellSpec, Effect, WallSpec};
use crate::timestep::near_implicit::CouplingMode;

/// The factor `c` of the default contact distance `d_min = c · R_min / p`.
pub const CONTACT_DISTANCE_PER_ORDER: f64 = 0.4;

/// The coupling a scene gets when it does not name one (module docs); `plane`: the cells are
/// beside a plane wall.
pub fn auto_coupling(cells: &[CellSpec], plane: bool) -> CouplingMode {
    if cells.len() >= 2 || (plane && !cells.is_empty()) {
        CouplingMode::NearImplicit
    } else {
        CouplingMode::Explicit
    }
}

/// The contact distance a scene gets when it does not give one: `0.4 · R_min / p` where a cell
/// has another surface to meet (another cell, a wall, the plane wall when `plane`), `None` (no
/// projection) for a lone cell.
pub fn auto_contact_distance(
    cells: &[CellSpec],
    walls: &[WallSpec],
    plane: bool,
    order: usize,
) -> Option<f64> {
    if cells.len() < 2 && (cells.is_empty() || (walls.is_empty() && !plane)) {
        return None;
    }
    let r_min = cells.iter().map(|c| c.radius).fold(f64::INFINITY, f64::min);
    Some(CONTACT_DISTANCE_PER_ORDER * r_min / order as f64)
}

/// The effects that say what the coupling and the contacts are and where they came from.
pub fn effects(
    coupling: CouplingMode,
    coupling_given: bool,
    contact_distance: Option<f64>,
    contact_given: bool,
    cells: usize,
    plane: bool,
) -> [Effect; 2] {
    let coupling_reason = if coupling_given {
        format!("[numerics] coupling = \"{}\"", coupling.name())
    } else if coupling == CouplingMode::NearImplicit && cells < 2 {
        "near_implicit ([numerics] coupling = \"auto\" beside a plane wall: the cell's own \
         image is solved with its step)"
            .to_string()
    } else if coupling == CouplingMode::NearImplicit {
        "near_implicit ([numerics] coupling = \"auto\" with two or more cells: cells in each \
         other's near zone are solved as one system)"
            .to_string()
    } else {
        format!("{cells} cell: nothing to couple")
    };
    let contact_reason = match (contact_distance, contact_given) {
        (Some(d), true) => format!("[numerics] contact_distance = {d}: every gap >= {d}"),
        (Some(d), false) => format!(
            "every gap >= d_min = {d:.4} at the end of each step (the default 0.4·R_min/p; \
             contact_distance = 0 turns it off)"
        ),
        (None, true) => "[numerics] contact_distance = 0: no contact projection".to_string(),
        (None, false) if plane => "no cell: nothing to meet".to_string(),
        (None, false) => "one cell and no wall: nothing to meet".to_string(),
    };
    [
        Effect {
            name: "coupling",
            enabled: coupling == CouplingMode::NearImplicit,
            reason: coupling_reason,
        },
        Effect {
            name: "contacts",
            enabled: contact_distance.is_some(),
            reason: contact_reason,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::cells::parse;
    use std::path::Path;

    fn scene(cells: &str, numerics: &str) -> crate::scene::cells::CellScene {
        let text = format!(
            "[[cells]]\nshape = \"sphere\"\nradius = 1.0\n{cells}\n[numerics]\norder = 8\n{numerics}\n"
        );
        parse(Path::new("t.toml"), &text).unwrap()
    }

    /// The defaults follow the cells: near-implicit and contacts at 0.4 R_min/p with two cells,
    /// neither for one; a given value (0 included) wins.
    #[test]
    fn defaults_follow_the_cells_and_given_values_win() {
        let one = scene("viscosity_ratio = 5.0", "");
        assert_eq!(one.numerics.coupling, CouplingMode::Explicit);
        assert_eq!(one.numerics.contact_distance, None);
        let pair = "count = 2\nplacement = \"lattice\"\nspacing = 3.0";
        let contrast = scene(&format!("{pair}\nviscosity_ratio = 5.0"), "");
        assert_eq!(contrast.numerics.coupling, CouplingMode::NearImplicit);
        assert_eq!(contrast.numerics.contact_distance, Some(0.05));
        let plain = scene(pair, "");
        assert_eq!(plain.numerics.coupling, CouplingMode::NearImplicit);
        assert_eq!(plain.numerics.contact_distance, Some(0.05));
        let given = scene(
            &format!("{pair}\nviscosity_ratio = 5.0"),
            "coupling = \"explicit\"\ncontact_distance = 0",
        );
        assert_eq!(given.numerics.coupling, CouplingMode::Explicit);
        assert_eq!(given.numerics.contact_distance, None);
        let auto = scene(pair, "coupling = \"auto\"\ncontact_distance = 0.1");
        assert_eq!(auto.numerics.coupling, CouplingMode::NearImplicit);
        assert_eq!(auto.numerics.contact_distance, Some(0.1));
        let names: Vec<_> = contrast.effects.iter().map(|e| e.name).collect();
        assert!(names.contains(&"coupling") && names.contains(&"contacts"));
    }
}
