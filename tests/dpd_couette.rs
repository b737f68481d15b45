//! Couette flow of the DPD fluid between sliding plane walls (`flow = "couette"`): the profile
//! in the channel is the exact linear one, `u_x = U (2z − lo − hi)/gap`, to within the slip
//! at the walls; scene errors for a Couette flow without plane walls or speed.

mod common;

use std::path::Path;

use common::{mobo, summary, tmpdir};
use mobo::scene::dpd::parse;

const SCENE: &str = r#"[dpd]
box = [6.0, 6.0, 12.0]
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.01
steps = 3000
seed = 2
walls = { kind = "planes", gap = 10.0 }
wall_warmup = 100
flow = "couette"
wall_speed = 1.0
equilibrate = 500
bins = 20
save_every = 1000
"#;

#[test]
fn couette_scene_errors() {
    let ok = parse(Path::new("c.toml"), SCENE).unwrap();
    assert_eq!(ok.wall_speed, 1.0);
    let e = parse(
        Path::new("c.toml"),
        &SCENE.replace("walls = { kind = \"planes\", gap = 10.0 }\n", ""),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("sliding plane walls"), "{e}");
    let e = parse(
        Path::new("c.toml"),
        &SCENE.replace("wall_speed = 1.0\n", ""),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("wall_speed") && e.contains("required"), "{e}");
    let e = parse(
        Path::new("c.toml"),
        &SCENE.replace("flow = \"couette\"", "flow = \"poiseuille\"\nforce = 0.1"),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("only flow = \"couette\" slides the walls"),
        "{e}"
    );
}

/// The fitted shear rate against the no-slip `2U/gap`: DPD walls of frozen particles slip
/// (only the dissipative force drags the fluid along a wall whose particles do not move; the
/// profile extrapolates to the wall speed about 1.4 r_c behind the wall for this fluid, so the
/// rate in a gap of 10 r_c is about 0.79 of the nominal one); the profile is linear.
#[test]
fn couette_profile_is_linear_with_the_wall_speed() {
    let dir = tmpdir("couette");
    let scene = dir.join("c.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = dir.join("out");
    let o = mobo(&[
        "dpd",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sum = summary(&out);
    let fitted = sum["shear_rate"]["fitted"].as_f64().unwrap();
    let nominal = sum["shear_rate"]["nominal"].as_f64().unwrap();
    assert_eq!(nominal, 0.2);
    println!("shear rate {fitted:.4} (nominal {nominal})");
    assert!(
        fitted > 0.7 * nominal && fitted < 1.02 * nominal,
        "fitted {fitted} vs nominal {nominal}"
    );
    assert_eq!(sum["leaked_particles"].as_u64(), Some(0));
    // The profile: linear within the noise in the middle of the channel.
    let profile = std::fs::read_to_string(out.join("profile.csv")).unwrap();
    let rows: Vec<(f64, f64)> = profile
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
            (c[0], c[1])
        })
        .filter(|(z, _)| (z - 6.0).abs() < 3.5)
        .collect();
    for (z, v) in &rows {
        let line = fitted * (z - 6.0);
        assert!((v - line).abs() < 0.08, "z = {z}: u = {v}, line {line}");
    }
}
