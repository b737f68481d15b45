//! `mpirun -n K mobo run` gives the one-rank result (K = 1…4, oversubscribed on this machine):
//! after 20 steps of the 125-RBC example suspension, and of a suspension of Skalak cells with
//! a viscosity contrast stepped by BDF2 while cells move between ranks at every step, every
//! cell's coefficients agree with the one-process run to 1e-10 relative. A run checkpointed
//! at 2 ranks resumes at 2 ranks bit for bit and at 3 and 1 ranks to 1e-10; a failing step
//! ends every rank with one message naming the step and the cell and leaves the last
//! checkpoint as it was; SIGUSR1 and Ctrl-C on `mpirun` stop every rank with a checkpoint.
//! Cells between rigid walls (a container and an obstacle) give the one-rank result on 2 and 3
//! ranks to 1e-10, with the walls' system replicated on every rank (the default for small
//! walls) and split over the ranks.
//! `mpirun -n K mobo brownian` writes the one-process trajectory byte for byte.
//!
//! Needs `mpirun` (Debian's `openmpi-bin`) and the `mpi` feature (the binary must be built
//! with MPI).

mod common;

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use common::tmpdir;
use mobo::io::npy;

/// `mpirun -n k mobo ARGS` (k = 0: the binary alone, no MPI).
fn mobo_on(k: usize, args: &[&str]) -> Output {
    let mut c = if k == 0 {
        Command::new(env!("CARGO_BIN_EXE_mobo"))
    } else {
        let mut c = Command::new("mpirun");
        c.args([
            "--allow-run-as-root",
            "--oversubscribe",
            "-n",
            &k.to_string(),
        ])
        .arg(env!("CARGO_BIN_EXE_mobo"));
        c
    };
    // Shared memory without CMA single copy (containers forbid ptrace between ranks). One
    // rayon thread everywhere: four oversubscribed ranks on two cores would otherwise each
    // start a pool as wide as the machine (results do not depend on it: see CONTRAST).
    c.env("OMPI_MCA_btl_vader_single_copy_mechanism", "none")
        .env("RAYON_NUM_THREADS", "1")
        .args(args)
        .output()
        .expect("run mpirun (openmpi-bin)")
}

/// `mobo run SCENE --out OUT --quiet EXTRA…` on `k` ranks (0: no MPI).
fn run_scene(k: usize, scene: &str, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["run", scene, "--out", out.to_str().unwrap(), "--quiet"];
    args.extend_from_slice(extra);
    mobo_on(k, &args)
}

fn ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what}: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The coefficients of the last frame, per cell.
fn last_coefs(out: &Path) -> Vec<Vec<f64>> {
    let (_, times) = npy::read_f64(&out.join("frames/times.npy")).unwrap();
    let last = times.len() - 1;
    let (shape, data) =
        npy::read_f64(&out.join(format!("frames/frame_{last:05}_coefs.npy"))).unwrap();
    let per = data.len() / shape[0];
    data.chunks_exact(per).map(|c| c.to_vec()).collect()
}

/// Largest over the cells of `max |a − b| / max |b|`.
fn worst_rel(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            let d = x
                .iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max);
            let s = y.iter().map(|q| q.abs()).fold(0.0, f64::max);
            if d == 0.0 {
                0.0
            } else {
                d / s
            }
        })
        .fold(0.0, f64::max)
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// The 125-RBC example at its settings, 20 steps, one frame at the end.
fn example_125(dir: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("examples/scenes/rbc_suspension.toml")).unwrap();
    let text = text
        .replace("t_end = 0.1", "t_end = 1.0")
        .replace("every = 2", "every = 20");
    assert!(text.contains("t_end = 1.0") && text.contains("count = 125"));
    write(dir, "rbc125.toml", &text)
}

/// Twelve Skalak cells, half of them with a viscosity contrast, in two layers close enough for
/// near-singular corrections between them, in shear, BDF2; the split is checked at every step
/// and any imbalance moves cells. No spheres: an inextensible sphere of fixed volume cannot
/// deform, so a constant tension is (nearly) in the null space of its step system and GMRES
/// leaves that component to round-off. With the second layer spheres, one and two rayon
/// threads (or one and four ranks) are bit-equal for 7 steps, then part by ×5–10 a step and
/// level off at 5e-4 relative in the sphere centres by step 24; with prolate spheroids of
/// reduced volume 0.95 they stay within 4e-15 (measured 2026-11-25, see docs/scaling.md).
/// The contact projection keeps every gap at least 0.3 (it moves cells in two of the 20 steps:
/// every rank solves the same projection of the gathered surfaces).
const CONTRAST: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
radius = 1.0
count = 6
placement = "random"
region = [[-5.0, -5.0, -0.2], [5.0, 5.0, 3.2]]
seed = 3
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 3.0

[[cells]]
shape = "prolate"
reduced_volume = 0.95
radius = 0.8
count = 6
placement = "random"
region = [[-5.0, -5.0, -3.4], [5.0, 5.0, -0.3]]
seed = 22
bending_modulus = 0.1
shear_modulus = 0.5

[numerics]
order = 6
dt = 0.01
t_end = 0.2
scheme = "bdf2"
gmres_tol = 1e-8
fmm_digits = 6
rebalance_every = 1
max_imbalance = 0.0
contact_distance = 0.3
coupling = "explicit"

[output]
every = 20
vtk = false
checkpoint_every = 1
"#;

#[test]
fn the_125_rbc_suspension_gives_the_one_rank_result_on_2_3_4_ranks() {
    let dir = tmpdir("mpi-run-125");
    let scene = example_125(&dir);
    let scene = scene.to_str().unwrap();
    let one = dir.join("k0");
    ok(&run_scene(0, scene, &one, &[]), "one process");
    let reference = last_coefs(&one);
    assert_eq!(reference.len(), 125);
    for k in [2, 3, 4] {
        let out = dir.join(format!("k{k}"));
        let o = run_scene(k, scene, &out, &[]);
        ok(&o, &format!("{k} ranks"));
        let e = worst_rel(&last_coefs(&out), &reference);
        eprintln!("125 RBCs, {k} ranks: largest relative difference {e:.2e}");
        assert!(e <= 1e-10, "{k} ranks differ from one by {e:.2e}");
        let s = summary(&out);
        assert_eq!(s["steps"].as_u64(), Some(20));
        let split = &s["split"];
        assert_eq!(split["ranks"].as_u64(), Some(k as u64));
        let cells = split["cells_per_rank"].as_array().unwrap();
        assert_eq!(cells[1].as_f64().unwrap() * k as f64, 125.0);
        assert!(cells[0].as_f64().unwrap() >= 1.0, "a rank without cells");
        assert!(split["ghost_cells_per_step"][0].as_f64().unwrap() > 0.0);
        // Where the FMM's time and bytes went: the build and the communication are parts of
        // the FMM's seconds; every phase is reported; points cross ranks at the cuts.
        let f = |key: &str, i: usize| split[key][i].as_f64().unwrap();
        for key in ["fmm_build_s", "fmm_comm_s"] {
            assert!(
                f(key, 0) > 0.0 && f(key, 0) <= f("fmm_s", 0),
                "{key}: {split}"
            );
        }
        let phases = split["fmm_phases_max_s"].as_object().unwrap();
        assert_eq!(phases.len(), 9, "{phases:?}");
        assert!(phases.values().all(|v| v.as_f64().unwrap() >= 0.0));
        assert!(phases["p2p"].as_f64().unwrap() > 0.0);
        assert!(f("fmm_points_moved_per_step", 0) > 0.0);
        assert!(f("fmm_setup_bytes_per_step", 0) > 0.0);
        // Every rank's peak memory (a rank is a process of some MiB at least; the largest is
        // at least the mean).
        let rss = [f("peak_rss_mib", 0), f("peak_rss_mib", 1)];
        eprintln!("125 RBCs, {k} ranks: peak MiB per rank {rss:?}");
        assert!(rss[1] > 1.0 && rss[0] >= rss[1], "{rss:?}");
    }
}

/// [`CONTRAST`] with the near cells inside the solve: all twelve cells form one cluster at
/// every step, spread over the ranks (one GMRES over all of them).
fn contrast_near_implicit() -> String {
    CONTRAST.replace("coupling = \"explicit\"", "coupling = \"near_implicit\"")
}

#[test]
fn contrast_and_skalak_cells_moving_between_ranks_give_the_one_rank_result() {
    let dir = tmpdir("mpi-run-contrast");
    // The explicit coupling on 1 and 4 ranks, the near-implicit one on 2 and 3.
    let cases = [
        ("explicit", CONTRAST.to_string(), [1, 4]),
        ("near_implicit", contrast_near_implicit(), [2, 3]),
    ];
    for (coupling, text, ranks) in cases {
        let scene = write(&dir, &format!("{coupling}.toml"), &text);
        let scene = scene.to_str().unwrap();
        let one = dir.join(format!("{coupling}-k0"));
        ok(&run_scene(0, scene, &one, &[]), "one process");
        let reference = last_coefs(&one);
        let s1 = summary(&one);
        assert!(s1["counters"]["double_layer_fmm_builds"].as_u64().unwrap() > 0);
        let joint = &s1["counters"]["near_implicit"];
        if coupling == "near_implicit" {
            assert_eq!(joint["largest"], 12, "{joint}");
        } else {
            assert_eq!(joint["clusters"], 0, "{joint}");
        }
        for k in ranks {
            let out = dir.join(format!("{coupling}-k{k}"));
            let o = run_scene(k, scene, &out, &[]);
            ok(&o, &format!("{coupling}, {k} ranks"));
            let e = worst_rel(&last_coefs(&out), &reference);
            let s = summary(&out);
            let moved: u64 = s["split"]["rebalances"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r["cells_moved"].as_u64().unwrap())
                .sum();
            eprintln!("contrast + Skalak, {coupling}, {k} ranks: {e:.2e}, {moved} cell moves");
            assert!(
                e <= 1e-10,
                "{coupling}: {k} ranks differ from one by {e:.2e}"
            );
            // Two ranks keep their halves (the costs stay balanced); three and four move cells.
            if k > 2 {
                assert!(
                    moved > 0,
                    "{k} ranks: no cell moved, the test misses migration"
                );
            }
            // The contacts move the same cells whatever the split.
            let contacts = &s["counters"]["contacts"];
            assert_eq!(
                contacts["moves"], s1["counters"]["contacts"]["moves"],
                "{coupling}, {k} ranks"
            );
            assert!(
                contacts["moves"].as_u64().unwrap() > 0,
                "no contact moved a cell"
            );
            assert!(contacts["smallest_gap"].as_f64().unwrap() >= 0.3);
            // The same work whatever the split, and the same joint solves.
            for c in [
                "double_layer_assemblies",
                "double_layer_fmm_builds",
                "fmm_builds",
                "near_implicit",
            ] {
                assert_eq!(
                    s["counters"][c], s1["counters"][c],
                    "{c}, {coupling}, {k} ranks"
                );
            }
        }
    }
}

/// Five cells with the near cells inside the solve: two RBCs 0.2 apart (`λ = 3`), a prolate
/// vesicle and an RBC near each other far from them, and an RBC alone. On four ranks one pair
/// is held by one rank and the other spread over two: a cluster stepped by its rank alone, a
/// cluster solved over ranks and a cell stepped alone in the same step.
const NEAR_GROUPS: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
center = [-8.0, 0.0, 0.0]
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 3.0

[[cells]]
shape = "rbc"
center = [-8.0, 0.0, 1.2]
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 3.0

[[cells]]
shape = "prolate"
reduced_volume = 0.9
center = [8.0, 0.2, 0.0]
bending_modulus = 0.1
viscosity_ratio = 3.0

[[cells]]
shape = "rbc"
center = [8.0, 0.0, 2.1]
orientation = [1, 0, 0, 30]
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 3.0

[[cells]]
shape = "rbc"
center = [0.0, 9.0, 0.0]
bending_modulus = 0.1
shear_modulus = 1.0

[numerics]
order = 6
dt = 0.01
t_end = 0.1
scheme = "bdf2"
coupling = "near_implicit"

[output]
every = 10
vtk = false
"#;

#[test]
fn near_clusters_on_one_rank_and_across_ranks_give_the_one_rank_result() {
    let dir = tmpdir("mpi-run-near-groups");
    let scene = write(&dir, "groups.toml", NEAR_GROUPS);
    let scene = scene.to_str().unwrap();
    let one = dir.join("k0");
    ok(&run_scene(0, scene, &one, &[]), "one process");
    let s1 = summary(&one);
    // Two clusters of two cells at each of the 10 steps.
    let joint = &s1["counters"]["near_implicit"];
    assert_eq!(
        (joint["clusters"].as_u64(), joint["largest"].as_u64()),
        (Some(20), Some(2))
    );
    let out = dir.join("k4");
    ok(&run_scene(4, scene, &out, &[]), "4 ranks");
    let e = worst_rel(&last_coefs(&out), &last_coefs(&one));
    eprintln!("near clusters, 4 ranks: {e:.2e}");
    // The sums of the inner products over ranks change the round-off only (the same scene with
    // λ = 5 and the pairs 0.09 apart differs by 2e-9: as much as one rank's run with each
    // inner product summed in two halves, docs/hard_cases.md).
    assert!(e <= 1e-10, "4 ranks differ from one by {e:.2e}");
    assert_eq!(summary(&out)["counters"]["near_implicit"], *joint);
}

/// Four RBCs (`λ = 3`) in shear inside an ellipsoidal container, with a fixed sphere as an
/// obstacle and contacts on: cells move between ranks every step, every rank gathers every
/// cell's layers at the walls, and the walls' system is split over the ranks (each holds the
/// rows of its band of the walls, solved by GMRES over them) or replicated.
const WALLS: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
count = 4
placement = "random"
region = [[-4.0, -4.0, -1.6], [4.0, 4.0, 1.6]]
seed = 5
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 3.0

[[walls]]
kind = "container"
shape = "ellipsoid"
axes = [6.0, 6.0, 4.5]
order = 12

[[walls]]
kind = "body"
shape = "sphere"
radius = 0.6
center = [0.0, 0.0, -2.9]
order = 8

[numerics]
order = 6
dt = 0.01
t_end = 0.06
scheme = "bdf2"
contact_distance = 0.1
rebalance_every = 1
max_imbalance = 0.0
# The cells are compared to 1e-10, which needs their state to round-off (the explicit
# coupling's). Near-implicit (the default for this scene), 2 ranks against one, one thread:
# tension 5e-10 apart (a GMRES over the ranks), the plane 2.8e-8 (7e-6 of its largest value).
coupling = "explicit"

[output]
every = 6
vtk = false
velocity_plane = { origin = [-5.8, -5.8, -2.9], u = [11.6, 0.0, 0.0], v = [0.0, 11.6, 0.0], points = [15, 15] }
"#;

/// The last frame's velocity plane of a run in `out`.
fn last_plane(out: &Path) -> Vec<f64> {
    let times = mobo::io::npy::read_f64(&out.join("frames/times.npy"))
        .unwrap()
        .1;
    let f = out.join(format!(
        "frames/frame_{:05}_plane_velocity.npy",
        times.len() - 1
    ));
    mobo::io::npy::read_f64(&f).unwrap().1
}

#[test]
fn cells_between_walls_give_the_one_rank_result_on_2_and_3_ranks() {
    let dir = tmpdir("mpi-run-walls");
    let scene = write(&dir, "walls.toml", WALLS);
    let scene = scene.to_str().unwrap();
    let one = dir.join("k0");
    ok(&run_scene(0, scene, &one, &[]), "one process");
    let reference = last_coefs(&one);
    let s1 = summary(&one);
    // One wall solve per step and per start-up pass (the passes agree over the ranks).
    let passes = s1["counters"]["start_up"]["passes"].as_u64().unwrap();
    assert_eq!(s1["counters"]["walls"]["solves"].as_u64(), Some(6 + passes));
    let whole_bytes = s1["counters"]["walls"]["operator_bytes"].as_u64().unwrap();
    // Small walls stay whole on every rank by default (`wall_solve = "auto"`): each rank
    // solves the whole system alone. Split, each rank holds its band's rows.
    let split = write(
        &dir,
        "split.toml",
        &WALLS.replace(
            "coupling = \"explicit\"",
            "coupling = \"explicit\"\nwall_solve = \"split\"",
        ),
    );
    let split = split.to_str().unwrap();
    let runs = [
        (2, scene, "replicated"),
        (2, split, "split"),
        (3, split, "split"),
    ];
    for (k, file, how) in runs {
        let out = dir.join(format!("k{k}-{how}"));
        ok(&run_scene(k, file, &out, &[]), &format!("{k} ranks"));
        let e = worst_rel(&last_coefs(&out), &reference);
        eprintln!("cells between walls, {k} ranks, {how}: largest relative difference {e:.2e}");
        assert!(e <= 1e-10, "{k} ranks ({how}) differ from one by {e:.2e}");
        let s = summary(&out);
        let walls = &s["counters"]["walls"];
        assert_eq!(walls["solves"].as_u64(), Some(6 + passes));
        let bytes = walls["operator_bytes"].as_u64().unwrap();
        if how == "split" {
            // Each rank holds its band's rows (and their block's factors), not the whole
            // operator; the solves are GMRES iterations over the ranks.
            assert_eq!(walls["split_ranks"].as_u64(), Some(k as u64));
            assert!(walls["split_iterations"].as_u64().unwrap() > 6 + passes);
            assert!(bytes < whole_bytes, "{bytes} bytes of {whole_bytes}");
        } else {
            assert_eq!(walls["split_ranks"].as_u64(), Some(1));
            assert_eq!(bytes, whole_bytes);
            // The cells' layers at the wall points are summed over the ranks block by block
            // (`comm::sum_in_rank_order`): a rank sends its sum's blocks and its own summed
            // block, `2 (K − 1)/K` of the `3 N_wall` values a solve (plus the agreements'
            // few words), whatever the number of cells.
            let unknowns = walls["unknowns"].as_u64().unwrap() as f64;
            let sent = walls["exchange_bytes"].as_u64().unwrap() as f64 / (6 + passes) as f64;
            let sum = 2.0 * (k as f64 - 1.0) / k as f64 * unknowns * 8.0;
            assert!(
                sent >= sum && sent <= sum + 1024.0,
                "{k} ranks: {sent} bytes a solve for the walls, the sum takes {sum}"
            );
        }
        // The velocity plane (through the body: NaN inside it and beyond the container),
        // summed over the ranks. Inside the container at rest the walls' layers cancel the
        // shear (up to 4.5 on the container) to a few thousandths, and their near-zone
        // evaluation next to the walls turns a change of 1e-14 of the densities (a GMRES
        // solve against a direct one, or the cells' sums added over the ranks in another
        // order) into about 3e-9 (`timestep::wall_rows_solve`'s unit test): the plane is held
        // to 1e-8 of the flow the walls carry (measured: 1.2e-9 to 2.9e-9).
        let (a, b) = (last_plane(&out), last_plane(&one));
        let tol = 1e-8 * 4.5;
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(
                x.is_nan(),
                y.is_nan(),
                "{k} ranks ({how}): the plane's fluid differs"
            );
            if y.is_finite() {
                assert!(
                    (x - y).abs() <= tol,
                    "{k} ranks ({how}): plane {x} against {y}"
                );
            }
        }
        assert!(b.iter().any(|v| v.is_nan()) && b.iter().any(|v| v.is_finite()));
    }
}

/// Three vesicles in shear beside the plane wall y = 0, the middle one with a viscosity
/// contrast (Blake's images of every cell's single layer and of its double layer, gathered
/// over the ranks in the cells' global order), near-implicit: the three cells and their
/// images are one cluster, split over the ranks (its GMRES sums over them).
const PLANE: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "prolate"
reduced_volume = 0.9
radius = 0.8
center = [-2.2, 1.5, 0.0]
bending_modulus = 0.5

[[cells]]
shape = "prolate"
reduced_volume = 0.9
radius = 0.8
center = [0.0, 2.0, 0.3]
bending_modulus = 0.5
viscosity_ratio = 3.0

[[cells]]
shape = "prolate"
reduced_volume = 0.9
radius = 0.8
center = [2.2, 1.4, -0.2]
bending_modulus = 0.5

[[walls]]
kind = "body"
shape = "plane"
normal = [0.0, 1.0, 0.0]

[numerics]
order = 6
dt = 0.02
t_end = 0.12
coupling = "near_implicit"
rebalance_every = 1
max_imbalance = 0.0

[output]
every = 6
vtk = false
velocity_plane = { origin = [-3.0, -0.5, 0.0], u = [6.0, 0.0, 0.0], v = [0.0, 4.0, 0.0], points = [9, 9] }
"#;

#[test]
fn cells_beside_a_plane_wall_give_the_one_rank_result_on_2_ranks() {
    let dir = tmpdir("mpi-run-plane");
    let scene = write(&dir, "plane.toml", PLANE);
    let scene = scene.to_str().unwrap();
    let one = dir.join("k0");
    ok(&run_scene(0, scene, &one, &[]), "one process");
    let reference = last_coefs(&one);
    let out = dir.join("k2");
    ok(&run_scene(2, scene, &out, &[]), "2 ranks");
    let e = worst_rel(&last_coefs(&out), &reference);
    eprintln!("cells beside a plane, 2 ranks: largest relative difference {e:.2e}");
    assert!(e <= 1e-10, "2 ranks differ from one by {e:.2e}");
    let (s1, s2) = (summary(&one), summary(&out));
    assert_eq!(
        s1["counters"]["plane_wall"]["evaluations"],
        s2["counters"]["plane_wall"]["evaluations"]
    );
    // One cluster of all three cells (their images link them), so split over the two ranks.
    assert_eq!(s2["counters"]["near_implicit"]["largest"].as_u64(), Some(3));
    // The velocity plane: NaN below the wall, the same field above it. It takes the tension,
    // which a GMRES over the ranks (its inner products summed rank by rank) leaves within its
    // tolerance 1e-8 of one rank's: measured 2.8e-9 of the field's largest value.
    let (a, b) = (last_plane(&out), last_plane(&one));
    let scale = b
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0_f64, |m, v| m.max(v.abs()));
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.is_nan(), y.is_nan(), "the plane's fluid differs");
        if y.is_finite() {
            assert!((x - y).abs() <= 1e-8 * scale, "plane {x} against {y}");
        }
    }
    assert!(b.iter().any(|v| v.is_nan()) && b.iter().any(|v| v.is_finite()));
}

#[test]
fn checkpoints_resume_bit_for_bit_on_as_many_ranks_and_on_other_counts_to_1e10() {
    let dir = tmpdir("mpi-run-resume");
    let scene = write(&dir, "contrast.toml", CONTRAST);
    let scene = scene.to_str().unwrap();
    for resume_on in [2, 3, 1] {
        // The uninterrupted run at the count the run goes on with.
        let whole = dir.join(format!("whole{resume_on}"));
        ok(
            &run_scene(resume_on, scene, &whole, &[]),
            &format!("uninterrupted at {resume_on} ranks"),
        );
        let reference = last_coefs(&whole);
        let part = dir.join(format!("part{resume_on}"));
        let o = run_scene(2, scene, &part, &["--max-steps", "7"]);
        ok(&o, "stopped at 7 steps on 2 ranks");
        let o = mobo_on(
            resume_on,
            &["run", "--resume", part.to_str().unwrap(), "--quiet"],
        );
        ok(&o, &format!("resumed on {resume_on} ranks"));
        let got = last_coefs(&part);
        let e = worst_rel(&got, &reference);
        eprintln!(
            "checkpoint at 2 ranks, resumed on {resume_on}: {e:.2e} from the uninterrupted \
             {resume_on}-rank run{}",
            if got == reference {
                " (bit for bit)"
            } else {
                ""
            }
        );
        if resume_on == 2 {
            assert!(
                got == reference,
                "2 → 2 ranks is not bit-identical ({e:.2e})"
            );
        } else {
            // Other counts: the distributed FMM sums in another order (~1e-14 a step).
            assert!(e <= 1e-10, "2 → {resume_on} ranks: {e:.2e}");
        }
        assert_eq!(summary(&part)["steps"].as_u64(), Some(20));
    }
}

#[test]
fn a_failing_step_stops_every_rank_with_one_message_and_the_checkpoint_intact() {
    let dir = tmpdir("mpi-run-fail");
    for (coupling, text) in [
        ("explicit", CONTRAST.to_string()),
        ("near_implicit", contrast_near_implicit()),
    ] {
        let scene = write(&dir, &format!("{coupling}.toml"), &text);
        let out = dir.join(coupling);
        let o = run_scene(3, scene.to_str().unwrap(), &out, &["--max-steps", "2"]);
        ok(&o, "two steps");
        let checkpoint = std::fs::read(out.join("checkpoint.bin")).unwrap();
        // GMRES cannot meet this tolerance: the next step fails on every rank (with the
        // near-implicit coupling, in the joint solve over the ranks).
        let copy = out.join("scene.toml");
        let text = std::fs::read_to_string(&copy).unwrap();
        std::fs::write(
            &copy,
            text.replace("gmres_tol = 1e-8", "gmres_tol = 1e-300"),
        )
        .unwrap();
        let t = Instant::now();
        let o = mobo_on(3, &["run", "--resume", out.to_str().unwrap(), "--quiet"]);
        assert!(t.elapsed() < Duration::from_secs(600));
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        let lines: Vec<&str> = err
            .lines()
            .filter(|l| l.starts_with("mobo: error"))
            .collect();
        assert_eq!(lines.len(), 1, "{coupling}: one message from rank 0: {err}");
        // The explicit coupling names the first cell; a joint solve names no cell.
        let cell = coupling == "near_implicit" || lines[0].contains("cell 0");
        assert!(
            lines[0].contains("step 3") && cell && lines[0].contains("tol"),
            "{coupling}: {}",
            lines[0]
        );
        assert_eq!(
            std::fs::read(out.join("checkpoint.bin")).unwrap(),
            checkpoint,
            "{coupling}: the last checkpoint changed"
        );
    }
}

/// `mobo brownian SCENE --out OUT --quiet` on `k` ranks (0: no MPI).
fn brownian_on(k: usize, scene: impl AsRef<Path>, out: &Path) -> Output {
    let scene = scene.as_ref().to_str().unwrap();
    mobo_on(
        k,
        &["brownian", scene, "--out", out.to_str().unwrap(), "--quiet"],
    )
}

fn read(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn brownian_runs_give_the_one_rank_trajectory_bit_for_bit() {
    let dir = tmpdir("mpi-brownian");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
    // The 300-bead cloud (above the fused pass's parallel threshold; repulsion, SCE and
    // gravity), and the 20-bead TEA-HI chain and the exact-noise dimer, shortened.
    let shorten = |name: &str| {
        let text = std::fs::read_to_string(root.join(name)).unwrap();
        let text = text.replace("steps = 20000", "steps = 300");
        assert!(text.contains("steps = 300"), "{name}");
        write(&dir, name, &text)
    };
    let scenes = [
        (root.join("brownian_cloud.toml"), true),
        (shorten("brownian_polymer.toml"), true),
        (shorten("brownian_dimer.toml"), false),
    ];
    for (scene, split) in scenes {
        let scene = scene.to_str().unwrap();
        let one = dir.join("one");
        let o = brownian_on(0, scene, &one);
        ok(&o, &format!("{scene}: one process"));
        for k in [2, 3, 4] {
            let out = dir.join(format!("k{k}"));
            let o = brownian_on(k, scene, &out);
            ok(&o, &format!("{scene}: {k} ranks"));
            for f in ["trajectory.npy", "observables.csv"] {
                assert!(
                    read(&out.join(f)) == read(&one.join(f)),
                    "{scene}: {k} ranks: {f} differs from one process"
                );
            }
            let s = summary(&out);
            assert_eq!(s["split"]["ranks"].as_u64(), Some(k as u64));
            assert_eq!(s["split"]["noise_split"].as_bool(), Some(split));
            assert!(summary(&one)["split"].is_null());
        }
    }
}

#[test]
fn a_brownian_run_that_blows_up_stops_every_rank_with_one_message() {
    let dir = tmpdir("mpi-brownian-fail");
    // A stiff chain with a step far beyond its bond relaxation time.
    let scene = write(
        &dir,
        "blow.toml",
        r#"
[brownian]
radius = 1.0
kT = 1.0
viscosity = 0.05305164769729845
dt = 0.5
steps = 400
seed = 5
noise = "tea-hi"

[brownian.system]
kind = "chain"
beads = 12
bond_length = 2.0
bond_stiffness = 1e6
repulsion = 50.0
"#,
    );
    let out = dir.join("out");
    let one = brownian_on(0, &scene, &out);
    assert!(!one.status.success(), "one process should fail");
    let message = String::from_utf8_lossy(&one.stderr)
        .lines()
        .find(|l| l.contains("left the finite numbers"))
        .expect("the one-process error")
        .to_string();
    let o = brownian_on(3, &scene, &out);
    assert!(!o.status.success(), "3 ranks should fail");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        err.matches("left the finite numbers").count(),
        1,
        "one message from rank 0: {err}"
    );
    assert!(
        err.contains(&message),
        "the same error as one process: {err}"
    );
    assert!(!out.join("trajectory.npy").exists(), "no partial output");
}

/// SIGUSR1 (forwarded by mpirun) and Ctrl-C (SIGINT to mpirun; OpenMPI 4.1 then sends the
/// ranks SIGCONT, SIGTERM after `odls_base_sigkill_timeout` seconds and SIGKILL as many
/// seconds later, so the ranks have that long to finish the step) stop every rank after the
/// step in progress, with a checkpoint from which the run goes on.
#[test]
fn sigusr1_and_ctrl_c_on_mpirun_stop_every_rank_with_a_checkpoint() {
    let dir = tmpdir("mpi-run-signal");
    // Long enough to outlast Ctrl-C's SIGTERM, which comes 15 s after the signal (below): at
    // about 0.1 s a step here the 90 steps of t_end = 0.9 could end first on a fast machine
    // left to this test alone; the stopped runs end long before t_end.
    let scene = write(
        &dir,
        "long.toml",
        &CONTRAST.replace("t_end = 0.2", "t_end = 5.0"),
    );
    for signal in ["USR1", "INT"] {
        let out = dir.join(signal);
        let mut c = Command::new("mpirun");
        c.args(["--allow-run-as-root", "--oversubscribe", "-n", "2"])
            .arg(env!("CARGO_BIN_EXE_mobo"))
            .args([
                "run",
                scene.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .arg("--quiet")
            .env("OMPI_MCA_btl_vader_single_copy_mechanism", "none")
            .env("OMPI_MCA_odls_base_sigkill_timeout", "15")
            .env("RAYON_NUM_THREADS", "1")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped());
        // As from a terminal: a test harness started in the background may have SIGINT
        // ignored, which mpirun would inherit.
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            c.pre_exec(|| {
                libc::signal(libc::SIGINT, libc::SIG_DFL);
                libc::signal(libc::SIGTERM, libc::SIG_DFL);
                Ok(())
            });
        }
        let child = c.spawn().expect("run mpirun (openmpi-bin)");
        // Signal once three checkpoints were written (one a step: the run is past its setup
        // and stepping steadily).
        let t = Instant::now();
        let mut seen = Vec::new();
        while seen.len() < 3 {
            assert!(
                t.elapsed() < Duration::from_secs(300),
                "{signal}: no checkpoints"
            );
            if let Ok(m) = std::fs::metadata(out.join("checkpoint.bin")).and_then(|m| m.modified())
            {
                if !seen.contains(&m) {
                    seen.push(m);
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let kill = Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let o = child.wait_with_output().unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            !o.status.success(),
            "{signal}: an interrupted run exits non-zero"
        );
        let stderr = String::from_utf8_lossy(&o.stderr);
        // The summary of the stopped run: not completed, the step of the checkpoint.
        let s = summary(&out);
        assert_eq!(
            s["completed"].as_bool(),
            Some(false),
            "{signal}: not stopped\n{stdout}\n{stderr}"
        );
        let step = s["steps"].as_u64().unwrap();
        assert!(step < 500, "{signal}: ran to the end");
        assert_eq!(
            stderr.matches("stopping after this step").count(),
            usize::from(signal == "INT"),
            "{signal}: rank 0 alone says it is stopping\n{stderr}"
        );
        // Rank 0's last words; with Ctrl-C mpirun may drop them (its I/O forwarding waits
        // in the kill sequence), so only SIGUSR1 is held to them.
        if signal == "USR1" {
            assert_eq!(
                stdout.matches(&format!("stopped at step {step} ")).count(),
                1,
                "{stdout}"
            );
        }
        // The checkpoint holds that step: one more step from it.
        let o = mobo_on(
            2,
            &[
                "run",
                "--resume",
                out.to_str().unwrap(),
                "--max-steps",
                "1",
                "--quiet",
            ],
        );
        ok(&o, &format!("{signal}: resumed"));
        assert_eq!(summary(&out)["steps"].as_u64(), Some(step + 1), "{signal}");
    }
}
