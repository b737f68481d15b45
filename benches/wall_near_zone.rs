//! What a wall's near zone costs and how accurate it is: the double layer of a tube wall
//! evaluated by `OffSurface` at points at known distances inside it, for several settings,
//! against a reference of twice the smooth rule's order.
//!
//! `cargo bench --bench wall_near_zone`. One thread.
//!
//! The tube is the 20 µm one of docs/blood_in_tubes.md (radius 3.57, length 16, order 40), the
//! density a smooth field, the targets 40 points at each distance `d` from the wall (moved
//! inward along the normal from grid points spread over the tube), the distances those of a
//! suspension's cells (0.05 is `d_min`).

use std::time::Instant;

use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::{
    Geometry, LayerKernel, NearParams, OffSurface, RotationAlgorithm, SelfInteraction,
    SurfaceCalculus,
};
use mobo::wall::tube_surface;

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    pool.install(run);
}

fn run() {
    let (p, radius, length) = (40, 3.57, 16.0);
    let tube = tube_surface(p, radius, length).expect("tube");
    let mut g = Geometry::zeros(p);
    SurfaceCalculus::new(p)
        .expect("calculus")
        .update_geometry(tube.coefs(), &mut g)
        .expect("geometry");
    let sht = ShTransform::new(p).expect("sht");
    let n = sht.n_points();
    let dens_of = |x: [f64; 3]| {
        [
            1.0 - (x[1] * x[1] + x[2] * x[2]) / (radius * radius) + 0.2 * (0.4 * x[0]).sin(),
            0.3 * (0.5 * x[0] + 0.7 * x[1]).cos(),
            0.2 * (0.3 * x[2] - 0.2 * x[0]).sin(),
        ]
    };
    let mut dens = vec![0.0; 3 * n];
    for (j, x) in g.x.iter().enumerate() {
        let d = dens_of(*x);
        for c in 0..3 {
            dens[c * n + j] = d[c];
        }
    }
    // The on-surface (principal) values, which a wall's solve holds (`own_double_layer`).
    let mut on_surface = vec![0.0; 3 * n];
    SelfInteraction::new(p, 2 * p, RotationAlgorithm::ViaSh)
        .expect("self interaction")
        .evaluate(
            LayerKernel::DoubleLayer,
            tube.coefs(),
            &dens,
            &mut on_surface,
        )
        .expect("on-surface values");
    let distances = [0.05, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0, 1.3];
    let per = 40;
    let mut targets = vec![];
    let mut seed: u64 = 12345;
    for &d in &distances {
        for _ in 0..per {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let j = (seed >> 33) as usize % n;
            let (x, nv) = (g.x[j], g.normal[j]);
            let s = (nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2]).sqrt();
            targets.push(std::array::from_fn(|c| x[c] - d * nv[c] / s));
        }
    }
    let nt = targets.len();
    let eval = |params: NearParams| -> (Vec<f64>, f64, usize) {
        let mut near = OffSurface::new(p, params).expect("off-surface");
        near.set_surface(tube.coefs()).expect("surface");
        let mut out = vec![0.0; 3 * nt];
        // Warm-up (builds any refined level), then timed.
        let kernel = LayerKernel::DoubleLayer;
        near.evaluate_given_on_surface(kernel, &dens, &on_surface, &targets, &mut out)
            .expect("evaluate");
        let t = Instant::now();
        let infos = near
            .evaluate_given_on_surface(kernel, &dens, &on_surface, &targets, &mut out)
            .expect("evaluate");
        let secs = t.elapsed().as_secs_f64();
        (out, secs, infos.iter().filter(|i| i.near).count())
    };
    let reference = NearParams {
        far_order: Some(12 * p),
        ..NearParams::default()
    };
    let (want, t_ref, _) = eval(reference);
    let size = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    // The reference's own check: the order-12p smooth rule alone where it resolves.
    let direct = NearParams {
        far_order: Some(12 * p),
        near_distance: Some(0.04),
        ..NearParams::default()
    };
    let (alt, _, _) = eval(direct);
    let want = &want;
    let err_at = |got: &[f64], k: usize| -> f64 {
        (k * per..(k + 1) * per)
            .flat_map(|i| (0..3).map(move |c| (got[c * nt + i] - want[c * nt + i]).abs()))
            .fold(0.0, f64::max)
            / size
    };
    println!(
        "Tube radius {radius}, length {length}, order {p}; {per} targets at each distance; \
         reference: far rule of order {} ({t_ref:.2} s). Largest error at each distance, \
         relative to the largest value {size:.3}:\n",
        12 * p
    );
    let mut configs: Vec<(String, NearParams)> = vec![
        ("default (6p)".into(), NearParams::default()),
        (
            "far order 4p".into(),
            NearParams {
                far_order: Some(4 * p),
                ..NearParams::default()
            },
        ),
        (
            "far order 3p".into(),
            NearParams {
                far_order: Some(3 * p),
                ..NearParams::default()
            },
        ),
    ];
    configs.push((
        "walls' settings (wall::NEAR_ZONE)".into(),
        mobo::wall::NEAR_ZONE,
    ));
    for r in [1.5, 2.0, 3.0] {
        configs.push((
            format!("6p, smooth ratio {r}"),
            NearParams {
                smooth_ratio: Some(r),
                ..NearParams::default()
            },
        ));
    }
    for delta in [0.2, 0.4] {
        configs.push((
            format!("6p, δ = {delta}"),
            NearParams {
                near_distance: Some(delta),
                ..NearParams::default()
            },
        ));
    }
    print!("| setting | seconds | near |");
    for d in distances {
        print!(" {d} |");
    }
    println!();
    println!("|---|---|---|{}", "---|".repeat(distances.len()));
    print!("| reference, smooth rule alone | - | - |");
    for k in 0..distances.len() {
        print!(" {:.1e} |", err_at(&alt, k));
    }
    println!();
    for (name, params) in configs {
        let (got, secs, n_near) = eval(params);
        print!("| {name} | {secs:.2} | {n_near} |");
        for k in 0..distances.len() {
            print!(" {:.1e} |", err_at(&got, k));
        }
        println!();
    }
}
