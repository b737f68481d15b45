//! The GPU backend (feature `gpu`) against the CPU: the near field of every kernel on the three
//! clouds in each precision the adapter offers, an all-pairs sum against `direct_sum`, and the
//! FMM with its near field on the GPU against direct sums at 3 and 6 digits.
//!
//! Without a GPU these run on Mesa's lavapipe (scripts/test.sh installs it). Where no adapter
//! exists they skip with a message, except in CI (`CI=true`), where that is a failure.

use std::sync::Arc;

use mobo::fmm::blocks::SourceBlock;
use mobo::fmm::clouds::Cloud;
use mobo::fmm::gpu_near::{choose, gpu_kernel};
use mobo::fmm::near_field::{CpuNearField, NearField};
use mobo::fmm::{direct_sum, order_for_digits, Fmm, FmmError, FmmKernel, SumInput};
use mobo::gpu::p2p::{PairPoints, PairSum, RowList};
use mobo::gpu::{Gpu, GpuChoice, GpuError, GpuPrecision};

const KERNELS: [FmmKernel; 5] = [
    FmmKernel::Laplace,
    FmmKernel::LaplaceDoubleLayer,
    FmmKernel::Stokeslet,
    FmmKernel::Stresslet,
    // Overlapping pairs (r < 2a) in the near field of all three clouds.
    FmmKernel::Rpy { radius: 0.004 },
];
const CLOUDS: [Cloud; 3] = [Cloud::Uniform, Cloud::Blobs, Cloud::Spheres];

/// The process's GPU, or `None` (with a message) where there is none outside CI.
fn gpu() -> Option<Arc<Gpu>> {
    match Gpu::shared() {
        Ok(g) => {
            eprintln!("GPU: {} (f64: {})", g.describe(), g.has_f64());
            Some(g)
        }
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => {
            panic!("CI=true and no GPU adapter: {e}")
        }
        Err(e) => {
            eprintln!("skipping the GPU tests: {e}");
            None
        }
    }
}

fn precisions(g: &Gpu) -> Vec<GpuPrecision> {
    if g.has_f64() {
        vec![GpuPrecision::F32, GpuPrecision::F64]
    } else {
        vec![GpuPrecision::F32]
    }
}

/// Relative L2 difference.
fn rel(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

/// Tolerance of a GPU sum against the CPU's `f64` loops: `f64` differs only in the order of
/// the sums; `f32` by the rounding of each pair's value (see `mobo::gpu`).
fn tolerance(p: GpuPrecision) -> f64 {
    match p {
        GpuPrecision::F64 => 1e-12,
        GpuPrecision::F32 => 1e-6,
    }
}

#[test]
fn near_field_matches_the_cpu_for_every_kernel_cloud_and_precision() {
    let Some(g) = gpu() else { return };
    let n = 4000;
    let mut worst = Vec::new();
    for cloud in CLOUDS {
        let pts = cloud.points(n, 3);
        let nrm = Cloud::unit_vectors(n, 4);
        for kind in KERNELS {
            let near = kind.near();
            let ds = near.density_dim();
            let dens = Cloud::densities(n * ds, 5);
            // A leaf size well below the default gives many rows and ranges.
            let fmm = Fmm::new(kind, &pts, Some(&nrm), &pts, 6, 120).unwrap();
            let list = fmm.near_list();
            assert!(list.pairs() > 0);
            let pts_sorted = fmm.near_points();
            let (src, normals, tgt) = (pts_sorted.sources, pts_sorted.normals, pts_sorted.targets);
            let identity: Vec<usize> = (0..src.len()).collect();
            let mut block = SourceBlock::new(src, normals, &identity);
            // The FMM sorts sources; densities here are simply per sorted source.
            block.set_density(&dens, ds, &identity);
            let dt = near.output_dim();
            let mut want = vec![0.0; tgt.len() * dt];
            CpuNearField::new(kind.near())
                .evaluate(list, &block, tgt, &mut want)
                .unwrap();
            for prec in precisions(&g) {
                let sum = PairSum::new(
                    g.clone(),
                    gpu_kernel(kind),
                    prec,
                    PairPoints {
                        sources: src,
                        normals,
                        targets: tgt,
                    },
                    RowList {
                        rows: &list.rows,
                        offsets: &list.offsets,
                        ranges: &list.ranges,
                    },
                )
                .unwrap();
                assert_eq!(sum.pairs(), list.pairs());
                let q: Vec<&[f64]> = block.q[..ds].iter().map(|c| c.as_slice()).collect();
                let mut got = vec![0.0; want.len()];
                sum.evaluate(&q, &mut got).unwrap();
                // Twice on the same device buffers: densities are the only input per call.
                let mut again = vec![0.0; want.len()];
                sum.evaluate(&q, &mut again).unwrap();
                assert_eq!(got, again);
                let e = rel(&got, &want);
                eprintln!(
                    "{:9} {:10} {}: {:.2e}",
                    cloud.name(),
                    near.name(),
                    prec.name(),
                    e
                );
                worst.push((e, tolerance(prec), cloud.name(), near.name(), prec));
            }
        }
    }
    let bad: Vec<_> = worst.iter().filter(|w| w.0.is_nan() || w.0 > w.1).collect();
    assert!(bad.is_empty(), "GPU near field off the CPU: {bad:?}");
}

#[test]
#[allow(clippy::single_range_in_vec_init)] // one-row lists are the point here
fn a_list_that_leaves_the_points_is_refused() {
    let Some(g) = gpu() else { return };
    let pts = Cloud::Uniform.points(100, 1);
    let points = PairPoints {
        sources: &pts,
        normals: None,
        targets: &pts,
    };
    let rows = [0..100];
    let bad: [(&[std::ops::Range<usize>], &[usize]); 3] = [
        (&[0..101], &[0, 1]),
        (&[0..50], &[0, 2]),
        (&[0..50], &[1, 0]),
    ];
    for (ranges, offsets) in bad {
        let list = RowList {
            rows: &rows,
            offsets,
            ranges,
        };
        let e = PairSum::new(
            g.clone(),
            mobo::gpu::GpuKernel::Laplace,
            GpuPrecision::F32,
            points,
            list,
        );
        assert!(
            matches!(e, Err(GpuError::Shape(_))),
            "{ranges:?} {offsets:?}"
        );
    }
}

#[test]
fn all_pairs_sum_matches_direct_sum() {
    // One row of all targets and one range of all sources: the RPY mobility product of
    // Brownian dynamics, with overlapping beads and the self term.
    let Some(g) = gpu() else { return };
    let n = 1500;
    let pts = Cloud::Blobs.points(n, 7);
    let a = 0.01;
    let dens = Cloud::densities(3 * n, 8);
    let mut want = vec![0.0; 3 * n];
    let input = SumInput {
        sources: &pts,
        density: &dens,
        normals: None,
        targets: &pts,
    };
    direct_sum(&mobo::fmm::Rpy { radius: a }, &input, &mut want).unwrap();
    let comps: Vec<Vec<f64>> = (0..3)
        .map(|c| (0..n).map(|i| dens[3 * i + c]).collect())
        .collect();
    let q: Vec<&[f64]> = comps.iter().map(|c| c.as_slice()).collect();
    for prec in precisions(&g) {
        let sum = PairSum::all_pairs(
            g.clone(),
            mobo::gpu::GpuKernel::Rpy { radius: a },
            prec,
            PairPoints {
                sources: &pts,
                normals: None,
                targets: &pts,
            },
        )
        .unwrap();
        let mut got = vec![0.0; 3 * n];
        sum.evaluate(&q, &mut got).unwrap();
        let e = rel(&got, &want);
        eprintln!("all pairs rpy {}: {e:.2e}", prec.name());
        assert!(e <= tolerance(prec), "{}: {e:e}", prec.name());
    }
}

/// Relative L2 error of an FMM evaluation against the direct sum at every `stride`-th target.
fn fmm_error(fmm: &mut Fmm, pts: &[[f64; 3]], dens: &[f64], kind: FmmKernel) -> f64 {
    let dt = kind.near().output_dim();
    let mut u = vec![0.0; pts.len() * dt];
    fmm.evaluate(dens, &mut u).unwrap();
    let idx: Vec<usize> = (0..pts.len()).step_by(7).collect();
    let tg: Vec<[f64; 3]> = idx.iter().map(|&i| pts[i]).collect();
    let mut want = vec![0.0; tg.len() * dt];
    let input = SumInput {
        sources: pts,
        density: dens,
        normals: None,
        targets: &tg,
    };
    direct_sum(kind.near().as_ref(), &input, &mut want).unwrap();
    let got: Vec<f64> = idx
        .iter()
        .flat_map(|&i| u[i * dt..(i + 1) * dt].to_vec())
        .collect();
    rel(&got, &want)
}

#[test]
fn fmm_with_the_gpu_near_field_meets_3_and_6_digits() {
    let Some(g) = gpu() else { return };
    let n = 12000;
    let pts = Cloud::Spheres.points(n, 11);
    for kind in [FmmKernel::Laplace, FmmKernel::Stokeslet] {
        let ds = kind.near().density_dim();
        let dens = Cloud::densities(n * ds, 12);
        for digits in [3u32, 6] {
            let order = order_for_digits(kind, digits).unwrap();
            let mut fmm =
                Fmm::new(kind, &pts, None, &pts, order, kind.default_leaf_size(order)).unwrap();
            let cpu_err = fmm_error(&mut fmm, &pts, &dens, kind);
            let mut precs = precisions(&g);
            precs.retain(|p| digits <= p.max_digits());
            for prec in precs {
                let d = choose(&mut fmm, GpuChoice::On, Some(prec), Some(digits)).unwrap();
                assert_eq!(d.device, "gpu");
                assert!(fmm.near_field_description().starts_with("gpu"));
                let err = fmm_error(&mut fmm, &pts, &dens, kind);
                eprintln!(
                    "{} {digits} digits: cpu {cpu_err:.2e}, gpu {} {err:.2e}",
                    kind.near().name(),
                    prec.name()
                );
                assert!(fmm.timings.near_concurrent);
                assert!(err < 10f64.powi(-(digits as i32)), "{err:e}");
                // The GPU changes the near field by its rounding only.
                assert!((err - cpu_err).abs() < 0.1 * 10f64.powi(-(digits as i32)));
            }
        }
    }
}

#[test]
fn choice_is_explained_and_refusals_are_errors() {
    let Some(g) = gpu() else { return };
    let pts = Cloud::Uniform.points(2000, 1);
    let mut fmm = Fmm::new(FmmKernel::Stokeslet, &pts, None, &pts, 4, 400).unwrap();
    let off = choose(&mut fmm, GpuChoice::Off, None, Some(3)).unwrap();
    assert_eq!(off.device, "cpu");
    let auto = choose(&mut fmm, GpuChoice::Auto, None, Some(3)).unwrap();
    if g.is_hardware() {
        // 2000 points: far below the pairs where the GPU gains.
        assert_eq!(auto.device, "cpu");
        assert!(auto.reason.contains("pairs"), "{}", auto.reason);
    } else {
        assert_eq!(auto.device, "cpu");
        assert!(
            auto.reason.contains("not a hardware GPU"),
            "{}",
            auto.reason
        );
    }
    assert_eq!(fmm.near_field_description(), "cpu");
    // f32 cannot serve 9 digits: `true` says so rather than quietly losing them.
    let e = choose(&mut fmm, GpuChoice::On, Some(GpuPrecision::F32), Some(9)).unwrap_err();
    assert!(matches!(e, FmmError::Gpu(GpuError::Shape(_))), "{e}");
    assert!(e.to_string().contains("9 digits"), "{e}");
}

mod common;

/// Two sedimenting vesicles, `[numerics] gpu = true` against `false`: the same trajectory to
/// the FMM's rounding, and summary.json says where the near field ran and why.
#[test]
fn a_cell_scene_with_gpu_true_follows_the_cpu_run() {
    let Some(_g) = gpu() else { return };
    let dir = common::tmpdir("gpu-scene");
    let run = |gpu: &str| {
        let text = format!(
            r#"
[[cells]]
shape = "sphere"
force = [0.0, 0.0, -1.0]
[[cells]]
shape = "prolate"
reduced_volume = 0.9
center = [2.6, 0.0, 0.0]
force = [0.0, 0.0, -1.0]
[numerics]
order = 6
dt = 0.05
t_end = 0.15
fmm_digits = 6
gpu = {gpu}
[output]
vtk = false
"#
        );
        let scene = common::write(&dir, &format!("two_{gpu}.toml"), &text);
        let out = dir.join(format!("out_{gpu}"));
        let o = common::mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        common::summary(&out)
    };
    let cpu = run("false");
    let gpu = run("true");
    assert_eq!(cpu["near_field"]["device"], "cpu");
    assert_eq!(gpu["near_field"]["device"], "gpu");
    assert!(gpu["near_field"]["adapter"].as_str().is_some());
    for c in 0..2 {
        for d in 0..3 {
            let a = cpu["per_cell"][c]["centroid"][d].as_f64().unwrap();
            let b = gpu["per_cell"][c]["centroid"][d].as_f64().unwrap();
            assert!((a - b).abs() < 1e-9, "cell {c} axis {d}: {a} vs {b}");
        }
    }
}

/// Per column `c` of rows of `w` values: relative L2 difference of `got` against `want`.
fn worst_column(got: &[f64], want: &[f64], w: usize) -> f64 {
    (0..w)
        .map(|c| {
            let a: Vec<f64> = got.iter().skip(c).step_by(w).copied().collect();
            let b: Vec<f64> = want.iter().skip(c).step_by(w).copied().collect();
            rel(&a, &b)
        })
        .fold(0.0, f64::max)
}

#[test]
fn tea_hi_pass_matches_the_cpu_rows() {
    use mobo::brownian::gpu_pass;
    use mobo::brownian::tea_hi::{fused_rows, Soa, ROW_VALUES};
    let Some(g) = gpu() else { return };
    let n = 1200;
    // Beads of radius 0.02 in blobs: overlapping pairs (r < 2a) and far ones.
    let a = 0.02;
    let pos = Soa::from_points(&Cloud::Blobs.points(n, 21));
    let vec3 = |seed| -> Soa {
        let d = Cloud::densities(3 * n, seed);
        Soa::from_points(
            &d.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>(),
        )
    };
    let (force, xi) = (vec3(22), vec3(23));
    for rows in [0..n, 250..731] {
        let mut want = Vec::new();
        fused_rows(&pos, &force, &xi, a, rows.clone(), &mut want);
        for prec in precisions(&g) {
            let (pass, d) = gpu_pass::choose(GpuChoice::On, Some(prec), n).unwrap();
            assert_eq!(d.device, "gpu");
            let mut got = Vec::new();
            pass.unwrap()
                .rows(&pos, &force, &xi, a, rows.clone(), &mut got)
                .unwrap();
            assert_eq!(got.len(), want.len());
            let e = worst_column(&got, &want, ROW_VALUES);
            eprintln!("tea-hi rows {rows:?} {}: {e:.2e}", prec.name());
            let tol = match prec {
                GpuPrecision::F64 => 1e-12,
                GpuPrecision::F32 => 5e-6,
            };
            assert!(e <= tol, "{} rows {rows:?}: {e:e}", prec.name());
        }
    }
}

#[test]
fn brownian_steps_with_the_gpu_pass_follow_the_cpu() {
    use mobo::brownian::{BrownianParams, BrownianSimulation, ForceField, NoiseModel};
    let Some(g) = gpu() else { return };
    let n = 600;
    let start: Vec<[f64; 3]> = Cloud::Uniform
        .points(n, 31)
        .iter()
        .map(|p| p.map(|c| 40.0 * c))
        .collect();
    let params = BrownianParams {
        radius: 1.0,
        kt: 1.0,
        viscosity: 1.0 / (6.0 * std::f64::consts::PI),
        dt: 1e-3,
        noise: NoiseModel::TeaHi,
        seed: 5,
    };
    let forces = ForceField {
        repulsion: 50.0,
        radius: 1.0,
        external: [0.0, 0.0, -1.0],
        ..Default::default()
    };
    let run = |gpu: Option<GpuPrecision>| {
        let mut sim = BrownianSimulation::new(params, start.clone(), forces.clone()).unwrap();
        if let Some(p) = gpu {
            let d = sim.use_gpu(GpuChoice::On, Some(p)).unwrap();
            assert_eq!(d.device, "gpu");
        }
        for _ in 0..10 {
            sim.step().unwrap();
        }
        (sim.positions, sim.last_tea_hi.unwrap())
    };
    let (cpu, coef) = run(None);
    for prec in precisions(&g) {
        let (got, c) = run(Some(prec));
        let tol = match prec {
            GpuPrecision::F64 => 1e-12,
            GpuPrecision::F32 => 1e-7,
        };
        let worst = got
            .iter()
            .zip(&cpu)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
            .fold(0.0, f64::max);
        eprintln!("brownian {} after 10 steps: {worst:.2e}", prec.name());
        assert!(worst <= tol * 40.0, "{}: {worst:e}", prec.name());
        assert!((c.epsilon - coef.epsilon).abs() <= tol * coef.epsilon.abs().max(1e-3));
    }
}

/// `mobo fmm --gpu` against `mobo fmm` on the same files: the same values to the FMM's
/// rounding, the JSON line saying where the near field ran; a bad `--gpu` value is refused.
#[test]
fn mobo_fmm_with_gpu_matches_the_cpu_run() {
    let Some(_g) = gpu() else { return };
    let dir = common::tmpdir("gpu-cli");
    let n = 5000;
    let pts = Cloud::Spheres.points(n, 41);
    let f = Cloud::densities(3 * n, 42);
    let flat: Vec<f64> = pts.iter().flatten().copied().collect();
    let (src, den) = (dir.join("x.npy"), dir.join("f.npy"));
    mobo::io::npy::write_f64(&src, &[n, 3], &flat).unwrap();
    mobo::io::npy::write_f64(&den, &[n, 3], &f).unwrap();
    let run = |extra: &[&str], out: &str| {
        let out = dir.join(out);
        let mut args = vec![
            "fmm",
            "--kernel",
            "stokeslet",
            "--sources",
            src.to_str().unwrap(),
            "--density",
            den.to_str().unwrap(),
            "--digits",
            "6",
            "--leaf-size",
            "600",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = common::mobo(&args);
        (o, out)
    };
    let (cpu, cpu_out) = run(&[], "cpu.npy");
    assert!(
        cpu.status.success(),
        "{}",
        String::from_utf8_lossy(&cpu.stderr)
    );
    let (gpu, gpu_out) = run(&["--gpu", "--repeat", "2"], "gpu.npy");
    assert!(
        gpu.status.success(),
        "{}",
        String::from_utf8_lossy(&gpu.stderr)
    );
    let line: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&gpu.stdout).trim()).unwrap();
    assert_eq!(line["near_field"]["device"], "gpu", "{line}");
    assert_eq!(line["repeat"], 2);
    assert_eq!(line["phases_s"]["near_concurrent"], true);
    let cpu_line: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&cpu.stdout).trim()).unwrap();
    assert_eq!(cpu_line["near_field"]["device"], "cpu");
    let (_, a) = mobo::io::npy::read_f64(&cpu_out).unwrap();
    let (_, b) = mobo::io::npy::read_f64(&gpu_out).unwrap();
    let e = rel(&b, &a);
    // At 6 digits the CPU's near field may refine 1/|r| by one Newton step (1e-7 per pair
    // allowed, `calibration::near_tolerance`); the GPU's f64 near field is exact.
    assert!(e < 1e-7, "GPU run off the CPU run by {e:e}");
    let (bad, _) = run(&["--gpu", "sometimes"], "bad.npy");
    assert!(!bad.status.success());
    let msg = String::from_utf8_lossy(&bad.stderr);
    assert!(msg.contains("--gpu takes auto, true or false"), "{msg}");
}
