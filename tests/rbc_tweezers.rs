//! Optical-tweezers stretching of a red blood cell by the boundary-integral solver against
//! Mills et al. (Mech. Chem. Biosyst. 1, 2004), at 88 pN and a low order (p = 8) so that it
//! runs in the default suite; `examples/rbc_tweezers.rs` runs the full comparison
//! (docs/bie_rbc_stretch.md).
//!
//! The cell: the biconcave RBC scaled to a diameter of 7.82 µm, Skalak `G_s = 6.3 µN/m`,
//! `κ = 2.4·10⁻¹⁹ J`, locally inextensible, pulled by `±88 pN` spread smoothly over the 2.5 %
//! of its area at each end (`SmoothPatchPair`, edge 10 % of the extent).
//!
//! What it shows: the axial diameter meets Mills' 13.07 µm within 10 %; the transverse one
//! does not. A membrane of these moduli that keeps its enclosed volume (the Stokes interior
//! keeps it exactly) is about 6.2 µm wide at 88 pN against Mills' 4.78 µm: the DPD model of
//! the same cell on a nearly uniform mesh gives 5.90 µm, and reaches Mills' width only when
//! its volume penalty is removed and the cell loses two thirds of its volume
//! (docs/dpd_rbc_stretch_sensitivity.md). The test pins that answer so that a change of it
//! is seen.

use std::path::Path;

use mobo::run::simulation::Simulation;
use mobo::scene::cells::parse;

/// The setup of `examples/rbc_tweezers.rs` (Mills' data, the cell's moduli and units, the
/// pull, the extent).
#[path = "../examples/common/tweezers.rs"]
mod tweezers;
use tweezers::{extent, pull, Units, DIAMETER_UM, MILLS, SHEAR_UN_PER_M};

#[test]
fn an_rbc_pulled_by_88_pn_reaches_mills_length_and_keeps_its_volume() {
    let units = Units::new(SHEAR_UN_PER_M);
    let r_um = units.r_um;
    let text = units.scene_text(8, 0.01, 6.0, "", "elasticity = \"implicit\"\n");
    let scene = parse(Path::new("rbc_tweezers test"), &text).unwrap();
    let mut sim = Simulation::new(scene).unwrap();
    pull(&mut sim, units.force(88.0), 0.025, 0.1);
    let (_, mills_da, mills_dt) = MILLS[1];
    let g0 = sim.cell(0).unwrap().geometry;
    let (a0, v0) = (g0.area(), g0.volume());
    assert!((extent(&g0, 0) * r_um - DIAMETER_UM).abs() < 0.05);
    sim.advance_to(6.0, |_, _| {}).unwrap();
    let g = sim.cell(0).unwrap().geometry;
    let (da, dt) = (extent(&g, 0) * r_um, extent(&g, 1) * r_um);
    println!(
        "88 pN, p = 8, t = 6: D_A = {da:.3} µm (Mills {mills_da}), D_T = {dt:.3} µm \
         (Mills {mills_dt}), area drift {:.1e}, volume drift {:.1e}",
        g.area() / a0 - 1.0,
        g.volume() / v0 - 1.0
    );
    // Measured 2026-11-27: D_A 12.21, D_T 6.22 µm at t = 6 (12.24 / 6.23 at t = 15; p = 12:
    // 12.48 / 6.17); area drift 3.5e-8, volume drift 1.1e-9.
    assert!((da / mills_da - 1.0).abs() < 0.1, "D_A = {da} µm");
    assert!((g.area() / a0 - 1.0).abs() < 1e-6);
    assert!((g.volume() / v0 - 1.0).abs() < 1e-6);
    // The volume-conserving answer, 25–35 % above Mills' 4.78 µm.
    assert!((5.9..6.5).contains(&dt), "D_T = {dt} µm (Mills {mills_dt})");
}
