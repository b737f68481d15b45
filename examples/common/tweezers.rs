//! The optical-tweezers setup of Mills et al. (Mech. Chem. Biosyst. 1, 2004) in the
//! simulation's units, shared by `examples/rbc_tweezers.rs`, `examples/tweezers_probe.rs` and
//! `tests/rbc_tweezers.rs` (included with `#[path]`; not an example of its own).
//!
//! The cell: the biconcave RBC scaled to a diameter of 7.82 µm (equivalent radius
//! `R = 7.82/(2α)` µm, `α` = [`RBC_ALPHA`]), bending rigidity `κ = 2.4·10⁻¹⁹ J` and a Skalak
//! shear modulus `G_s` (6.3 µN/m, Fedosov et al. 2010). In the simulation's units `R = 1`,
//! `G_s = 1`, `μ = 1`: a force `F` is `F/(G_s R)` and `κ` is `κ/(G_s R²)`.

use mobo::fmm::octree::bounding_box;
use mobo::run::simulation::Simulation;
use mobo::timestep::bead_pair::{BeadPair, BondedPatchPair};
use mobo::timestep::cell_force::{PatchPair, SmoothPatchPair};
use mobo::vesicle::geometry::Geometry;
use mobo::vesicle::shapes::RBC_ALPHA;

/// Mills et al. (2004): force (pN), axial and transverse diameters (µm).
pub const MILLS: [(f64, f64, f64); 3] =
    [(0.0, 7.78, 7.78), (88.0, 13.07, 4.78), (193.0, 15.29, 4.27)];
/// Cell diameter (µm), shear modulus (µN/m), bending rigidity (J).
pub const DIAMETER_UM: f64 = 7.82;
pub const SHEAR_UN_PER_M: f64 = 6.3;
pub const BENDING_J: f64 = 2.4e-19;
/// Diameter of the silica beads of Mills et al. (2004), µm.
#[allow(dead_code)] // not every includer pulls by beads
pub const BEAD_DIAMETER_UM: f64 = 4.12;

/// The cell's scales for a shear modulus `G_s` in µN/m.
pub struct Units {
    /// `R` in µm.
    pub r_um: f64,
    /// `κ/(G_s R²)`.
    pub kappa: f64,
    /// `G_s R` in newtons.
    force_n: f64,
}

impl Units {
    pub fn new(shear_un_per_m: f64) -> Self {
        let shear_n_per_m = shear_un_per_m * 1e-6;
        let r_um = DIAMETER_UM / (2.0 * RBC_ALPHA);
        let r_m = r_um * 1e-6;
        Units {
            r_um,
            kappa: BENDING_J / (shear_n_per_m * r_m * r_m),
            force_n: shear_n_per_m * r_m,
        }
    }

    /// A force of `f_pn` piconewtons as `F/(G_s R)`.
    pub fn force(&self, f_pn: f64) -> f64 {
        f_pn * 1e-12 / self.force_n
    }

    /// The scene of one free RBC (no flow) with this bending rigidity: `cell` is added to the
    /// `[[cells]]` entry and `numerics` to `[numerics]` (lines ending in a newline).
    pub fn scene_text(&self, p: usize, dt: f64, t_end: f64, cell: &str, numerics: &str) -> String {
        format!(
            "[flow]\nkind = \"none\"\n\n[[cells]]\nshape = \"rbc\"\nshear_modulus = 1.0\n\
             bending_modulus = {}\n{cell}\n[numerics]\norder = {p}\ndt = {dt}\nt_end = {t_end}\n\
             {numerics}",
            self.kappa
        )
    }
}

/// Pull cell 0 by `±force` (simulation units) along x, spread over the end patches of a share
/// `fraction` of its area each: a [`SmoothPatchPair`] whose edge is the share `edge` of the
/// extent, or the hard [`PatchPair`] for `edge = 0`.
pub fn pull(sim: &mut Simulation, force: f64, fraction: f64, edge: f64) {
    let pair = PatchPair {
        cell: 0,
        axis: [1.0, 0.0, 0.0],
        fraction,
        force,
    };
    if edge > 0.0 {
        sim.add_force(SmoothPatchPair { pair, width: edge });
    } else {
        sim.add_force(pair);
    }
}

/// Pull cell 0 by `±force` along x through two rigid beads of radius `radius` (simulation
/// units) bonded to the patches of [`pull`] with stiffness `stiffness` (a [`BeadPair`]).
#[allow(dead_code)] // not every includer pulls by beads
pub fn pull_by_beads(
    sim: &mut Simulation,
    force: f64,
    fraction: f64,
    edge: f64,
    radius: f64,
    stiffness: f64,
) {
    let pair = PatchPair {
        cell: 0,
        axis: [1.0, 0.0, 0.0],
        fraction,
        force,
    };
    sim.add_force(BeadPair {
        patches: SmoothPatchPair { pair, width: edge },
        radius,
        stiffness,
    });
}

/// Pull cell 0 by `±force` along x through the patches of [`pull`] glued (stiffness
/// `stiffness`) to rigid bodies that carry the force (a [`BondedPatchPair`]: the membrane's
/// grid must follow its material points, a capsule).
#[allow(dead_code)] // not every includer pulls by bonds
pub fn pull_by_bonds(sim: &mut Simulation, force: f64, fraction: f64, edge: f64, stiffness: f64) {
    let pair = PatchPair {
        cell: 0,
        axis: [1.0, 0.0, 0.0],
        fraction,
        force,
    };
    sim.add_force(BondedPatchPair::new(
        SmoothPatchPair { pair, width: edge },
        stiffness,
    ));
}

/// The largest distance from its bead's sphere of a point bonded with a weight of at least ½
/// (simulation units), for the beads of [`pull_by_beads`] on the cell `g`: how far the bond is
/// from rigid.
#[allow(dead_code)] // not every includer pulls by beads
pub fn bead_misfit(
    g: &Geometry,
    force: f64,
    fraction: f64,
    edge: f64,
    radius: f64,
    stiffness: f64,
) -> f64 {
    let pair = PatchPair {
        cell: 0,
        axis: [1.0, 0.0, 0.0],
        fraction,
        force,
    };
    let beads = BeadPair {
        patches: SmoothPatchPair { pair, width: edge },
        radius,
        stiffness,
    };
    let weights = beads.patches.weights(g);
    let mut worst: f64 = 0.0;
    for (bead, w) in beads.beads(g).iter().zip(&weights) {
        for (x, wj) in g.x.iter().zip(w) {
            if *wj >= 0.5 {
                let d = (0..3)
                    .map(|c| (x[c] - bead.centre[c]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                worst = worst.max((d - radius).abs());
            }
        }
    }
    worst
}

/// The extent of the cell's grid points along axis `d` (simulation units).
pub fn extent(g: &Geometry, d: usize) -> f64 {
    let (lo, hi) = bounding_box(&g.x);
    hi[d] - lo[d]
}
