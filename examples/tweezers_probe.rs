//! Probe of the optical-tweezers run at high force (docs/bie_rbc_stretch.md): every `EVERY`
//! time units, the axial diameter, the largest GMRES count since the last line, and the
//! spectral make-up of the Skalak reference's material labels and of the reference composed
//! from them (share of the energy above degree `p/2`), with the largest angle between a grid
//! point's label and its own parameter direction, and the largest membrane speed.
//!
//! ```text
//! cargo run --release --example tweezers_probe -- [ORDER FORCE_PN T_MAX DT EVERY CYCLES WEIGHTS]
//! ```
//!
//! At `T_MAX` it then freezes the cell and moves its grid alone, `CYCLES` times, by the
//! reparametrisation with the weight exponents `WEIGHTS` in turn (default `1,3,2`; a step
//! uses `s` = 2), ten iterations each, the material labels carried as in
//! a step: the Skalak energy `∫ W dA_ref` (G_s = 1, C = 10) of the same membrane must not
//! change, since no material point has moved; printed after every cycle with the axial
//! diameter.

use std::path::Path;

use mobo::run::simulation::Simulation;
use mobo::scene::cells::parse;
use mobo::sph_harmonics::layout::CoefLayout;
use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::membrane::Membrane;
use mobo::vesicle::reparam::{ReparamParams, Reparametrizer};
use mobo::vesicle::shapes::Surface;
use mobo::vesicle::skalak::SkalakParams;

/// The setup of `examples/rbc_tweezers.rs` (the cell's moduli and units, the pull, the extent).
#[allow(dead_code)]
#[path = "common/tweezers.rs"]
mod tweezers;
use tweezers::{extent, pull, Units, SHEAR_UN_PER_M};

/// Share of the energy of three functions' coefficients above degree `cut`.
fn tail_share(lay: &CoefLayout, coefs: &[f64], cut: usize) -> f64 {
    let deg = lay.degrees();
    let nc = lay.len();
    let (mut hi, mut all) = (0.0, 0.0);
    for c in coefs.chunks_exact(nc) {
        for (a, &n) in c.iter().zip(&deg) {
            all += a * a;
            if n > cut {
                hi += a * a;
            }
        }
    }
    hi / all
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, d: f64| -> Result<f64, Box<dyn std::error::Error>> {
        Ok(a.get(i).map_or(Ok(d), |s| s.parse())?)
    };
    let p = arg(0, 12.0)? as usize;
    let f_pn = arg(1, 193.0)?;
    let t_max = arg(2, 10.0)?;
    let dt = arg(3, 0.01)?;
    let every = arg(4, 0.25)?;
    let cycles = arg(5, 0.0)? as usize;
    let weights: Vec<u32> = a
        .get(6)
        .map_or("1,3,2", |s| s.as_str())
        .split(',')
        .map(|s| s.parse())
        .collect::<Result<_, _>>()?;
    let units = Units::new(SHEAR_UN_PER_M);
    let r_um = units.r_um;
    let text = units.scene_text(p, dt, t_max, "", "elasticity = \"implicit\"\n");
    let mut sim = Simulation::new(parse(Path::new("tweezers_probe"), &text)?)?;
    pull(&mut sim, units.force(f_pn), 0.025, 0.1);
    let sht = ShTransform::new(p)?;
    let lay = CoefLayout::new(p);
    let n = sht.n_points();
    println!("t D_A max_gmres label_tail ref_tail max_label_angle_deg max_speed");
    while sim.time() < t_max {
        let mut most = 0;
        let t = sim.time() + every;
        sim.advance_to(t, |_, r| {
            most = most.max(
                r.cells
                    .iter()
                    .map(|c| c.gmres.iterations)
                    .max()
                    .unwrap_or(0),
            );
        })?;
        let d_a = extent(&sim.cell(0)?.geometry, 0) * r_um;
        // The largest membrane speed of the last step (units of G_s/μ).
        let speed = sim.cell(0)?.membrane_velocity.map_or(f64::NAN, |u| {
            (0..n)
                .map(|j| u.point(j).iter().map(|v| v * v).sum::<f64>().sqrt())
                .fold(0.0, f64::max)
        });
        let st = &sim.suspension().cells()[0].state;
        let labels = st.material_labels.as_ref().ok_or("no labels")?;
        let reference = st.skalak_reference.as_deref().ok_or("no reference")?;
        let mut xi = vec![0.0; 3 * n];
        let mut ws = sht.workspace();
        sht.inverse(&labels.map, &mut xi, &mut ws)?;
        let mut worst: f64 = 0.0;
        for (j, u) in sht.grid().unit_points().iter().enumerate() {
            let v = [xi[j], xi[n + j], xi[2 * n + j]];
            let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let c = (v[0] * u[0] + v[1] * u[1] + v[2] * u[2]) / r;
            worst = worst.max(c.clamp(-1.0, 1.0).acos());
        }
        println!(
            "{:.2} {:.4} {most} {:.3e} {:.3e} {:.2} {speed:.2e}",
            sim.time(),
            d_a,
            tail_share(&lay, &labels.map, p / 2),
            tail_share(&lay, reference, p / 2),
            worst.to_degrees()
        );
    }
    // The grid moved alone: the energy of the same membrane before and after.
    let st = &sim.suspension().cells()[0].state;
    let mut labels = st.material_labels.as_ref().ok_or("no labels")?.clone();
    let mut coefs = sim.cell(0)?.coefs;
    let par = SkalakParams::skalak(1.0, 10.0);
    let mut membrane = Membrane::with_default_upsampling(p)?;
    let mut reference = vec![0.0; coefs.len()];
    let mut ws = sht.workspace();
    let mut energy = |coefs: &[f64], labels: &mobo::vesicle::material_labels::MaterialLabels| {
        labels.compose(&sht, &mut ws, &mut reference)?;
        membrane.set_geometry(coefs)?;
        membrane.set_reference(&reference)?;
        membrane.skalak_energy(&par)
    };
    let e0 = energy(&coefs, &labels)?;
    let mut ws2 = sht.workspace();
    let mut rp = Reparametrizer::new(p)?;
    println!("cycle relative_energy_change D_A");
    for cycle in 1..=cycles {
        for &s in &weights {
            let mut surf = Surface::from_coefs(p, coefs.clone())?;
            let params = ReparamParams {
                weight_exponent: s,
                max_iterations: 10,
                ..Default::default()
            };
            rp.run_with(&mut surf, &params, &mut [&mut labels.map[..]])?;
            coefs = surf.coefs().to_vec();
        }
        let e = energy(&coefs, &labels)?;
        let n = sht.n_points();
        let mut x = vec![0.0; 3 * n];
        sht.inverse(&coefs, &mut x, &mut ws2)?;
        let (lo, hi) = x[..n]
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(*v), h.max(*v)));
        println!("{cycle} {:.3e} {:.4}", e / e0 - 1.0, (hi - lo) * r_um);
    }
    Ok(())
}
