//! The drag on a spherical cell pulled through the DPD fluid (`dpd::suspension`), against
//! Stokes' law with Hasimoto's (1959) correction for a periodic array of spheres:
//!
//! ```text
//! F = 6πηRU / K(R/L),   K(c) = 1 − 2.8373 c + 4.19 c³ − 27.4 c⁶   (c = R/L),
//! ```
//!
//! the force balanced by a uniform force on the solvent (as a pressure gradient does in a
//! periodic array). The cell (an icosphere on the SH sphere, stiff membrane) is pulled along
//! `x` by FORCE; its mean velocity `U` over the steps after EQUIL is measured with a
//! standard error from block averages, and the hydrodynamic radius `R_h` that Stokes–Hasimoto
//! needs to give that velocity is reported beside the mesh radius. The fluid: a = 25, ρ = 3,
//! k_BT = 1, dissipation GAMMA with kernel exponent POWER, and its viscosity ETA ± ETA_ERR as
//! measured by periodic Poiseuille (`mobo dpd`): the standard fluid (γ = 4.5, k = 1) has
//! η = 0.917 ± 0.037 (docs/dpd_validation.md); γ = 45, k = 1/4 has η = 10.07 ± 0.18
//! (docs/dpd_cells.md).
//!
//! ```text
//! cargo run --release --example dpd_cell_drag -- \
//!     [L R SUBDIV FORCE STEPS EQUIL DT SEED GAMMA POWER ETA ETA_ERR]
//!   (defaults 12 2.5 3 3.6 200000 10000 0.005 1 4.5 1 0.917 0.037)
//! ```
use mobo::dpd::membrane::{BendingModel, MembraneParams, Moduli};
use mobo::dpd::pair_force::PairParams;
use mobo::dpd::suspension::{CellSpec, CouplingParams, DpdSuspension};
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
use mobo::vesicle::{shapes, CellMesh};

fn hasimoto(c: f64) -> f64 {
    1.0 - 2.8373 * c + 4.19 * c.powi(3) - 27.4 * c.powi(6)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, d: f64| -> Result<f64, Box<dyn std::error::Error>> {
        Ok(a.get(i).map(|s| s.parse::<f64>()).transpose()?.unwrap_or(d))
    };
    let (side, radius, sub, force) = (arg(0, 12.0)?, arg(1, 2.5)?, arg(2, 3.0)?, arg(3, 3.6)?);
    let (steps, equil, dt, seed) = (
        arg(4, 200_000.0)? as usize,
        arg(5, 10_000.0)? as usize,
        arg(6, 0.005)?,
        arg(7, 1.0)? as u64,
    );
    let (gamma, power, eta, eta_err) =
        (arg(8, 4.5)?, arg(9, 1.0)?, arg(10, 0.917)?, arg(11, 0.037)?);
    let pair = PairParams {
        a: 25.0,
        gamma,
        kbt: 1.0,
        rc: 1.0,
        power,
    };
    let params = DpdParams {
        box_len: [side; 3],
        pair,
        dt,
        mass: 1.0,
        seed,
    };
    let fluid = DpdSystem::random_fluid(params, 3.0, BodyForce::None)?;
    let mesh = CellMesh::icosphere(&shapes::sphere(8, radius)?, sub as u32)?;
    let lengths = mesh.edge_lengths();
    let l0 = lengths.iter().sum::<f64>() / lengths.len() as f64;
    let membrane = MembraneParams::from_moduli(&Moduli::new(
        100.0,
        20.0,
        BendingModel::Juelicher { c0: 2.0 / radius },
        l0,
    ))?;
    let c = 0.5 * side;
    let cell = CellSpec {
        vertices: mesh.vertices.iter().map(|v| v.map(|x| x + c)).collect(),
        triangles: mesh.triangles.clone(),
        params: membrane,
    };
    let mut sim = DpdSuspension::new(fluid, vec![cell], CouplingParams::default())?;
    sim.set_external_force(0, [force, 0.0, 0.0])?;
    println!(
        "box {side}, R {radius}, {} vertices (edge {l0:.3}), inner solvent {}, {} solvent, force {force}",
        mesh.vertices.len(),
        sim.inner_count(0),
        sim.fluid.len()
    );
    let t0 = std::time::Instant::now();
    for _ in 0..equil {
        sim.step()?;
    }
    // The cell's velocity relative to the solvent's mean (the solvent's mean moves against
    // the pull, the total momentum being zero).
    let n_blocks = 20;
    let per_block = (steps / n_blocks).max(1);
    let mut blocks = Vec::with_capacity(n_blocks);
    let mut temp = 0.0;
    for _ in 0..n_blocks {
        let x0 = sim.cells()[0].centroid()[0];
        let mut fluid_x = 0.0;
        for _ in 0..per_block {
            sim.step()?;
            let p = sim.fluid.momentum();
            fluid_x += p[0] / (sim.fluid.len() as f64 * sim.fluid.params.mass);
        }
        temp += sim.fluid.kinetic_temperature();
        let x1 = sim.cells()[0].centroid()[0];
        let u_cell = (x1 - x0) / (per_block as f64 * dt);
        blocks.push(u_cell - fluid_x / per_block as f64);
    }
    let nb = blocks.len() as f64;
    let u = blocks.iter().sum::<f64>() / nb;
    let var = blocks.iter().map(|b| (b - u).powi(2)).sum::<f64>() / (nb - 1.0);
    let u_err = (var / nb).sqrt();
    let k = hasimoto(radius / side);
    let u_stokes = force * k / (6.0 * std::f64::consts::PI * eta * radius);
    // R_h with F = 6πη R_h U / K(R_h/L), by bisection on (0, L/3).
    let excess = |r: f64| 6.0 * std::f64::consts::PI * eta * r * u / hasimoto(r / side) - force;
    let (mut lo, mut hi) = (1e-6, side / 3.0);
    let rh = if u > 0.0 && excess(lo) < 0.0 && excess(hi) > 0.0 {
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if excess(mid) < 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    } else {
        f64::NAN
    };
    let secs = t0.elapsed().as_secs_f64();
    let re = 3.0 * u * radius / eta;
    println!(
        "U = {u:.5} ± {u_err:.5} (20 blocks of {per_block} steps); Stokes–Hasimoto with the mesh \
         radius: {u_stokes:.5} (η = {eta} ± {eta_err}, K = {k:.4}); ratio {:.3} ± {:.3}; \
         R_h = {rh:.3} (R_h − R = {:.3}); Re_R = {re:.3}; fluid k_BT {:.4}; bounces {}, \
         leaked max {}; {:.2} ms/step, {secs:.0} s",
        u / u_stokes,
        (u_err / u_stokes).hypot(u / u_stokes * eta_err / eta),
        rh - radius,
        temp / n_blocks as f64,
        sim.bounces(),
        sim.max_leaked(),
        1e3 * secs / (steps + equil) as f64
    );
    Ok(())
}
