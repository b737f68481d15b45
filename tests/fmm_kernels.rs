//! Kernels and direct sums against independently written formulas, and `mobo fmm` on `.npy`
//! files: round trip and error messages.

mod common;
use common::*;

use std::f64::consts::PI;
use std::path::Path;

use mobo::check::assert_close;
use mobo::fmm::{
    direct_sum, Kernel, Laplace, LaplaceDoubleLayer, Rpy, Stokeslet, Stresslet, SumInput,
};
use mobo::io::npy;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn cloud(n: usize, seed: u64, scale: f64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            [
                rng.random_range(-scale..scale),
                rng.random_range(-scale..scale),
                rng.random_range(-scale..scale),
            ]
        })
        .collect()
}

/// The tensors written out component by component (the library uses vector forms).
fn reference(kernel: &str, a: f64, r: [f64; 3], q: &[f64], n: [f64; 3]) -> Vec<f64> {
    let d = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    let delta = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
    match kernel {
        "laplace" => vec![q[0] / (4.0 * PI * d)],
        "laplace-dl" => {
            vec![q[0] * (n[0] * r[0] + n[1] * r[1] + n[2] * r[2]) / (4.0 * PI * d.powi(3))]
        }
        "stokeslet" => (0..3)
            .map(|i| {
                (0..3)
                    .map(|j| (delta(i, j) / d + r[i] * r[j] / d.powi(3)) * q[j] / (8.0 * PI))
                    .sum()
            })
            .collect(),
        "stresslet" => (0..3)
            .map(|i| {
                let mut s = 0.0;
                for j in 0..3 {
                    for k in 0..3 {
                        s += 3.0 / (4.0 * PI) * r[i] * r[j] * r[k] / d.powi(5) * q[j] * n[k];
                    }
                }
                s
            })
            .collect(),
        "rpy" => {
            // M = (1/8πr)[(1 + 2a²/3r²) I + (1 − 2a²/r²) r̂r̂] for r ≥ 2a;
            // M = (1/6πa)[(1 − 9r/32a) I + (3r/32a) r̂r̂] for r < 2a.
            let (ci, cu) = if d >= 2.0 * a {
                (
                    1.0 / (8.0 * PI * d) * (1.0 + 2.0 * a * a / (3.0 * d * d)),
                    1.0 / (8.0 * PI * d) * (1.0 - 2.0 * a * a / (d * d)),
                )
            } else {
                (
                    1.0 / (6.0 * PI * a) * (1.0 - 9.0 * d / (32.0 * a)),
                    1.0 / (6.0 * PI * a) * 3.0 * d / (32.0 * a),
                )
            };
            (0..3)
                .map(|i| {
                    (0..3)
                        .map(|j| (ci * delta(i, j) + cu * r[i] * r[j] / (d * d)) * q[j])
                        .sum()
                })
                .collect()
        }
        _ => unreachable!(),
    }
}

fn check_kernel<K: Kernel>(k: &K, name: &str, a: f64) {
    let src = cloud(60, 1, 2.0);
    let tgt = cloud(40, 2, 2.0);
    let dd = k.density_dim();
    let mut rng = StdRng::seed_from_u64(3);
    let density: Vec<f64> = (0..src.len() * dd)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let normals = cloud(60, 4, 1.0);
    let input = SumInput {
        sources: &src,
        density: &density,
        normals: Some(&normals),
        targets: &tgt,
    };
    let mut got = vec![0.0; tgt.len() * k.output_dim()];
    direct_sum(k, &input, &mut got).unwrap();
    let mut want = vec![0.0; got.len()];
    for (i, x) in tgt.iter().enumerate() {
        for (j, y) in src.iter().enumerate() {
            let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
            let c = reference(name, a, r, &density[j * dd..(j + 1) * dd], normals[j]);
            for (o, v) in want[i * c.len()..(i + 1) * c.len()].iter_mut().zip(c) {
                *o += v;
            }
        }
    }
    assert_close(&format!("{name} direct sum"), &got, &want, 1e-13);
}

#[test]
fn every_kernel_matches_its_independent_formula() {
    check_kernel(&Laplace, "laplace", 0.0);
    check_kernel(&LaplaceDoubleLayer, "laplace-dl", 0.0);
    check_kernel(&Stokeslet, "stokeslet", 0.0);
    check_kernel(&Stresslet, "stresslet", 0.0);
    // Radius large enough that many pairs overlap (r < 2a).
    check_kernel(&Rpy { radius: 0.7 }, "rpy", 0.7);
}

#[test]
fn rpy_is_continuous_at_contact_and_self_terms_follow_the_contract() {
    let a = 0.5;
    let k = Rpy { radius: a };
    let f = [0.3, -0.2, 0.9];
    let at = |d: f64| {
        let mut o = [0.0; 3];
        k.accumulate([d * 0.6, d * 0.8, 0.0], &f, [0.0; 3], &mut o);
        o.to_vec()
    };
    assert_close(
        "RPY at r = 2a",
        &at(2.0 * a * (1.0 - 1e-13)),
        &at(2.0 * a),
        1e-11,
    );
    // Targets = sources: singular kernels leave out r = 0, RPY adds M0 f.
    let pts = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    let dens = vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    let input = SumInput {
        sources: &pts,
        density: &dens,
        normals: None,
        targets: &pts,
    };
    let mut u = vec![0.0; 6];
    direct_sum(&k, &input, &mut u).unwrap();
    assert!(
        (u[0] - 1.0 / (6.0 * PI * a)).abs() < 1e-15,
        "RPY self term {}",
        u[0]
    );
    direct_sum(&Stokeslet, &input, &mut u).unwrap();
    assert_eq!(
        &u[..3],
        &[0.0, 0.0, 0.0],
        "Stokeslet self term must be left out"
    );
    // Stokeslet at distance 1 along the force: (1/8π)(1 + 1) f.
    assert!((u[3] - 2.0 / (8.0 * PI)).abs() < 1e-15);
}

#[test]
fn mismatched_inputs_are_errors() {
    let pts = cloud(5, 1, 1.0);
    let bad = SumInput {
        sources: &pts,
        density: &[1.0; 4],
        normals: None,
        targets: &pts,
    };
    let mut u = vec![0.0; 5];
    assert!(direct_sum(&Laplace, &bad, &mut u).is_err());
    let ok = SumInput {
        sources: &pts,
        density: &[1.0; 15],
        normals: None,
        targets: &pts,
    };
    let mut u = vec![0.0; 15];
    assert!(
        direct_sum(&Stresslet, &ok, &mut u).is_err(),
        "stresslet without normals"
    );
}

fn save(dir: &Path, name: &str, shape: &[usize], data: &[f64]) -> String {
    let p = dir.join(name);
    npy::write_f64(&p, shape, data).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn cli_round_trip_on_npy_files() {
    let dir = tmpdir("rt");
    let src = cloud(50, 7, 1.0);
    let tgt = cloud(20, 8, 1.0);
    let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
    let s = save(&dir, "s.npy", &[50, 3], &flat(&src));
    let t = save(&dir, "t.npy", &[20, 3], &flat(&tgt));
    let f: Vec<f64> = (0..150).map(|i| (i as f64 * 0.37).sin()).collect();
    let q = save(&dir, "q.npy", &[50, 3], &f);
    let out = dir.join("u.npy");
    let o = mobo(&[
        "fmm",
        "--kernel",
        "stokeslet",
        "--sources",
        &s,
        "--targets",
        &t,
        "--density",
        &q,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let line = String::from_utf8_lossy(&o.stdout).trim().to_string();
    for key in [
        "\"kernel\":\"stokeslet\"",
        "\"n_sources\":50",
        "\"n_targets\":20",
        "\"digits\":6",
        "\"order\":",
        "\"setup_s\":",
        "\"eval_s\":",
    ] {
        assert!(line.contains(key), "{key} missing in {line}");
    }
    let (shape, u) = npy::read_f64(&out).unwrap();
    assert_eq!(shape, vec![20, 3]);
    let mut want = vec![0.0; 60];
    for (i, x) in tgt.iter().enumerate() {
        for (j, y) in src.iter().enumerate() {
            let c = reference(
                "stokeslet",
                0.0,
                [x[0] - y[0], x[1] - y[1], x[2] - y[2]],
                &f[3 * j..3 * j + 3],
                [0.0; 3],
            );
            for k in 0..3 {
                want[3 * i + k] += c[k];
            }
        }
    }
    // 6 digits asked: the near field may refine 1/|r| by one Newton step (1e-7 per pair
    // allowed at 6 digits, `calibration::near_tolerance`).
    assert_close("mobo fmm stokeslet", &u, &want, 1e-7);
    // Laplace charges as (N,) and output as (M,).
    let qs = save(&dir, "c.npy", &[50], &f[..50]);
    let o = mobo(&[
        "fmm",
        "--kernel",
        "laplace",
        "--sources",
        &s,
        "--density",
        &qs,
        "--direct",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(npy::read_f64(&out).unwrap().0, vec![50]);
}

#[test]
fn cli_fmm_matches_cli_direct_to_the_requested_digits() {
    let dir = tmpdir("fmmcli");
    let n = 4000;
    let src = mobo::fmm::clouds::Cloud::Spheres.points(n, 3);
    let flat: Vec<f64> = src.iter().flatten().copied().collect();
    let s = save(&dir, "s.npy", &[n, 3], &flat);
    let f = mobo::fmm::clouds::Cloud::densities(3 * n, 4);
    let q = save(&dir, "q.npy", &[n, 3], &f);
    let run = |extra: &[&str], out: &str| {
        let mut args = vec![
            "fmm",
            "--kernel",
            "stokeslet",
            "--sources",
            &s,
            "--density",
            &q,
        ];
        args.extend_from_slice(extra);
        args.extend(["--out", out]);
        let o = mobo(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let line = String::from_utf8_lossy(&o.stdout).trim().to_string();
        let (_, u) = npy::read_f64(Path::new(out)).unwrap();
        (line, u)
    };
    let fo = dir.join("fmm.npy");
    let dout = dir.join("direct.npy");
    let (line, u) = run(
        &["--digits", "4", "--leaf-size", "200"],
        fo.to_str().unwrap(),
    );
    assert!(line.contains("\"method\":\"fmm\""), "{line}");
    assert!(line.contains("\"order\":7"), "{line}");
    assert!(line.contains("\"tree_depth\":"), "{line}");
    let (dline, want) = run(&["--direct"], dout.to_str().unwrap());
    assert!(dline.contains("\"method\":\"direct\""), "{dline}");
    let err = (u
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / want.iter().map(|b| b * b).sum::<f64>())
    .sqrt();
    assert!(err < 1e-4 && err > 0.0, "fmm vs direct: {err:.2e}");
}

#[test]
fn cli_errors_name_the_file_and_the_problem() {
    let dir = tmpdir("err");
    let s = save(
        &dir,
        "s.npy",
        &[4, 3],
        &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    );
    let q3 = save(&dir, "q3.npy", &[4, 3], &[1.0; 12]);
    let q2 = save(&dir, "q2.npy", &[4, 2], &[1.0; 8]);
    let q5 = save(&dir, "q5.npy", &[5, 3], &[1.0; 15]);
    let mut nan = [1.0; 12];
    nan[7] = f64::NAN;
    let qn = save(&dir, "qnan.npy", &[4, 3], &nan);
    let junk = dir.join("junk.npy");
    std::fs::write(&junk, b"hello").unwrap();
    let junk = junk.to_str().unwrap().to_string();
    let out = dir.join("u.npy");
    let out = out.to_str().unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["--kernel", "stokeslet", "--sources", &s, "--density", &q2],
            "q2.npy",
        ),
        (
            vec!["--kernel", "stokeslet", "--sources", &s, "--density", &q5],
            "q5.npy",
        ),
        (
            vec!["--kernel", "stokeslet", "--sources", &s, "--density", &qn],
            "non-finite",
        ),
        (
            vec![
                "--kernel",
                "stokeslet",
                "--sources",
                &junk,
                "--density",
                &q3,
            ],
            "junk.npy",
        ),
        (
            vec!["--kernel", "stresslet", "--sources", &s, "--density", &q3],
            "--normals",
        ),
        (
            vec!["--kernel", "rpy", "--sources", &s, "--density", &q3],
            "--radius",
        ),
        (
            vec![
                "--kernel",
                "stokeslet",
                "--sources",
                &s,
                "--density",
                &q3,
                "--digits",
                "12",
            ],
            "--digits",
        ),
        (
            vec![
                "--kernel",
                "stokeslet",
                "--sources",
                &s,
                "--density",
                &q3,
                "--order",
                "1",
            ],
            "--order",
        ),
    ];
    for (args, expect) in cases {
        let mut full = vec!["fmm"];
        full.extend(args.iter());
        full.extend(["--out", out]);
        let o = mobo(&full);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{full:?} succeeded");
        assert!(err.contains(expect), "{full:?}: {err}");
        assert!(!err.contains("panicked"), "{full:?}: {err}");
    }
}
