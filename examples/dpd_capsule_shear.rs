//! A spherical capsule in Couette flow, simulated by DPD (`dpd::suspension`): its Taylor
//! deformation `D = (L − B)/(L + B)` and inclination in the shear plane, for comparison with
//! the boundary-integral capsule of the same moduli (`examples/capsule_shear.rs`;
//! `scripts/dpd_vs_bie.sh` runs both and writes docs/dpd_vs_bie.md).
//!
//! The fluid: a = 25, ρ = 3, k_BT = 1, γ = 45 with kernel exponent 1/4 and dt = 0.002, whose
//! viscosity η = 10.07 ± 0.18 was measured by periodic Poiseuille (docs/dpd_cells.md), in a
//! channel of gap 20 between plane walls sliding at ±U. The capsule: radius R = 3 (642
//! vertices), shear modulus μ0 = MU0, area modulus 2μ0 + k_a + k_d = 3μ0 (the small-strain
//! area modulus of a neo-Hookean or Skalak C = 1 membrane), volume kept by k_v = 5000, a small
//! bending rigidity κ = 2 k_BT with the sphere's spontaneous curvature (κ/(μ0R²) ≈ 0.01), no
//! membrane viscosity. The capillary number `Ca = η γ̇ R / μ0` uses the shear rate fitted to
//! the fluid's profile in the middle of the channel during the run.
//!
//! ```text
//! cargo run --release --example dpd_capsule_shear -- [U MU0 STEPS SETTLE SEED]
//!   (defaults 0.7 20 100000 40000 1; U = 0 measures the thermal deformation at rest)
//! ```
//!
//! Environment: `KBT` (default 1) sets the temperature of the fluid and of the solvent–membrane
//! coupling, the membrane's moduli unchanged (`μ0R²/k_BT` grows as `k_BT` falls); `A` (default
//! 25) the conservative force (`A = 25 KBT` keeps the fluid's structure, `a/k_BT`; at `a = 25`
//! the fluid at `k_BT = 0.25` is 1.5 times as viscous); `ETA` (default 10.07, the viscosity at
//! `k_BT = 1`, `a = 25`) the viscosity the capillary number uses, to be measured by periodic
//! Poiseuille at that state.
//!
//! The capsule needs a strain γ̇t of a few to reach its steady shape (the boundary-integral
//! capsule: 2.3 at Ca = 0.043, 5 at Ca = 0.09): at γ̇ ≈ 0.03–0.06 that is 40 000 steps.
use mobo::dpd::membrane::{BendingModel, MembraneParams, Moduli};
use mobo::dpd::pair_force::PairParams;
use mobo::dpd::suspension::{CellSpec, CouplingParams, DpdSuspension};
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
use mobo::dpd::walls::Wall;
use mobo::vesicle::{shapes, CellMesh};

/// The fluid's viscosity at `k_BT = 1` (periodic Poiseuille, docs/dpd_cells.md).
const ETA: f64 = 10.07;

/// A number from the environment variable `name`, or `default`.
fn env_f64(name: &str, default: f64) -> Result<f64, Box<dyn std::error::Error>> {
    match std::env::var(name) {
        Ok(v) => v
            .parse::<f64>()
            .map_err(|e| format!("{name} = {v:?}: {e}").into()),
        Err(_) => Ok(default),
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, d: f64| -> Result<f64, Box<dyn std::error::Error>> {
        Ok(a.get(i).map(|s| s.parse::<f64>()).transpose()?.unwrap_or(d))
    };
    let (u_wall, mu0) = (arg(0, 0.7)?, arg(1, 20.0)?);
    let (steps, settle, seed) = (
        arg(2, 100000.0)? as usize,
        arg(3, 40000.0)? as usize,
        arg(4, 1.0)? as u64,
    );
    let (kbt, a_cons, eta) = (
        env_f64("KBT", 1.0)?,
        env_f64("A", 25.0)?,
        env_f64("ETA", ETA)?,
    );
    let (radius, gap) = (3.0, 20.0);
    let box_len = [20.0, 14.0, gap + 2.0];
    let pair = PairParams {
        a: a_cons,
        gamma: 45.0,
        kbt,
        rc: 1.0,
        power: 0.25,
    };
    let params = DpdParams {
        box_len,
        pair,
        dt: 0.002,
        mass: 1.0,
        seed,
    };
    let wall = Wall::channel(gap, box_len[2], 1.0)?;
    let mut fluid = DpdSystem::with_wall(params, 3.0, BodyForce::None, wall, 200)?;
    if u_wall != 0.0 {
        fluid.start_couette(u_wall)?;
    }
    let mesh = CellMesh::icosphere(&shapes::sphere(12, radius)?, 3)?;
    let lengths = mesh.edge_lengths();
    let l0 = lengths.iter().sum::<f64>() / lengths.len() as f64;
    let membrane = MembraneParams::from_moduli(&Moduli {
        ka: 0.5 * mu0,
        kd: 0.5 * mu0,
        gamma_t: 0.0,
        gamma_c: Some(0.0),
        ..Moduli::new(mu0, 2.0, BendingModel::Juelicher { c0: 2.0 / radius }, l0)
    })?;
    let centre = [0.5 * box_len[0], 0.5 * box_len[1], 0.5 * box_len[2]];
    let cell = CellSpec {
        vertices: mesh
            .vertices
            .iter()
            .map(|v| [0, 1, 2].map(|k| v[k] + centre[k]))
            .collect(),
        triangles: mesh.triangles.clone(),
        params: membrane,
    };
    let mut sim = DpdSuspension::new(fluid, vec![cell], CouplingParams::default())?;
    let t0 = std::time::Instant::now();
    let (lo, hi) = match wall {
        Wall::Planes { lo, hi } => (lo, hi),
        _ => unreachable!("a channel"),
    };
    let mid = 0.5 * (lo + hi);
    // Samples of D and the inclination after SETTLE steps, every 50 steps; the shear rate from
    // the fluid's velocities in the middle 70 % of the channel.
    let (mut ds, mut thetas) = (Vec::new(), Vec::new());
    let (mut szz, mut szv, mut sz, mut sv, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for s in 1..=steps {
        sim.step()?;
        if s > settle && s % 50 == 0 {
            let (d, th) = sim.cells()[0].shear_plane_deformation();
            ds.push(d);
            thetas.push(th);
            let p = &sim.fluid.particles;
            for i in 0..p.len() {
                if p.moves[i] == 0.0 || (p.z[i] - mid).abs() > 0.35 * gap {
                    continue;
                }
                let z = p.z[i] - mid;
                szz += z * z;
                szv += z * p.vx[i];
                sz += z;
                sv += p.vx[i];
                n += 1.0;
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    // Standard error from 10 blocks.
    let stderr = |v: &[f64]| {
        let nb = 10;
        let per = (v.len() / nb).max(1);
        let b: Vec<f64> = v.chunks(per).take(nb).map(mean).collect();
        let m = mean(&b);
        (b.iter().map(|x| (x - m).powi(2)).sum::<f64>() / ((b.len() as f64 - 1.0) * b.len() as f64))
            .sqrt()
    };
    let rate = (szv - sz * sv / n) / (szz - sz * sz / n);
    let ca = eta * rate * radius / mu0;
    let (da, dv) = sim.cells()[0].area_volume_change()?;
    let secs = t0.elapsed().as_secs_f64();
    let sim_time = steps as f64 * 0.002;
    println!(
        "U {u_wall} mu0 {mu0} kbt {kbt} a {a_cons} eta {eta}: shear rate {rate:.5} (nominal {:.5}), Ca = eta*rate*R/mu0 = {ca:.4}; \
         D = {:.4} ± {:.4}, inclination {:.1} ± {:.1} deg ({} samples); area {da:+.4}, volume \
         {dv:+.4}; fluid k_BT (with the flow) {:.4}, vertex k_BT {:.4}; bounces {}, leaked max {}; {} solvent; \
         {secs:.0} s for t = {sim_time} ({:.1} s per unit time, {:.2} ms/step)",
        2.0 * u_wall / gap,
        mean(&ds),
        stderr(&ds),
        mean(&thetas),
        stderr(&thetas),
        ds.len(),
        sim.fluid.kinetic_temperature(),
        sim.vertex_temperature(),
        sim.bounces(),
        sim.max_leaked(),
        sim.fluid.n_moving(),
        secs / sim_time,
        1e3 * secs / steps as f64
    );
    Ok(())
}
