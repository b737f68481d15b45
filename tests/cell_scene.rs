//! Cell scene files: parsing, defaults, placement of many cells, the assembly decisions, and
//! located errors for every kind of bad scene.

use std::path::Path;

use mobo::scene::cells::{parse, Flow, Scheme, Shape, WallSolve};
use mobo::vesicle::geometry::SurfaceCalculus;

const FULL: &str = r#"
[fluid]
viscosity = 2.0

[flow]
kind = "shear"
rate = 0.5

[[cells]]
shape = "rbc"
radius = 1.5
center = [0.0, 0.0, 0.0]
bending_modulus = 0.1
shear_modulus = 0.2
viscosity_ratio = 5.0
force = [0.0, 0.0, -1.0]

[[cells]]
shape = "ellipsoid"
axes = [1.0, 0.8, 0.6]
center = [6.0, 0.0, 0.0]
orientation = [0, 0, 1, 90]

[numerics]
order = 8
upsample = 2
fmm_digits = 5
gmres_tol = 1e-7
dt = 0.005
t_end = 0.5
scheme = "bdf2"
adaptive_dt = true
far_side_split = false
operator_storage = "grid"
wall_solve = "replicated"

[output]
every = 4
"#;

fn file() -> &'static Path {
    Path::new("scene.toml")
}

#[test]
fn a_full_scene_parses_with_its_values_and_effects() {
    let s = parse(file(), FULL).unwrap();
    assert_eq!(s.viscosity, 2.0);
    assert_eq!(s.flow, Flow::Shear { rate: 0.5 });
    assert_eq!(s.flow.velocity([1.0, 2.0, 3.0]), [1.0, 0.0, 0.0]);
    assert_eq!(s.cells.len(), 2);
    assert_eq!(s.cells[0].shape, Shape::Rbc);
    assert_eq!(s.cells[0].line, 10);
    assert_eq!(s.cells[1].line, 19);
    assert_eq!(s.numerics.order, 8);
    assert_eq!(s.numerics.scheme, Scheme::Bdf2);
    assert!(s.numerics.adaptive_dt);
    assert!(!s.numerics.far_side_split);
    assert_eq!(s.numerics.wall_solve, WallSolve::Replicated);
    let plain = parse(file(), "[[cells]]\nshape = \"rbc\"\n").unwrap();
    assert!(plain.numerics.far_side_split);
    assert_eq!(plain.numerics.wall_solve, WallSolve::Auto);
    // The setting reaches every cell's own layer potentials.
    let susp = mobo::run::assembly::build(&s).unwrap();
    assert!(susp.steppers().iter().all(|c| !c.far_side_params().enabled));
    use mobo::timestep::semi_implicit::OperatorStorage;
    assert!(susp
        .steppers()
        .iter()
        .all(|c| c.operator_storage() == OperatorStorage::Grid));
    let default = parse(file(), "[[cells]]\nshape = \"rbc\"\n").unwrap();
    assert_eq!(default.numerics.operator_storage, None);
    // "auto": the fastest storage whose operators fit the budget. On the grid a cell keeps no
    // operator (the threads hold one each, its rows over coefficients: 3.8 MB at p = 12): 10⁴
    // RBCs at p = 12 fit in any budget that holds the threads' operators; coefficient space
    // keeps 2.0 MB per cell.
    let gib = 1u64 << 30;
    let mib = 1u64 << 20;
    assert_eq!(
        OperatorStorage::for_budget(100, 2, 12, 1, 14 * gib),
        OperatorStorage::Grid
    );
    assert_eq!(
        OperatorStorage::for_budget(10_000, 16, 12, 2, 24 * gib),
        OperatorStorage::Grid
    );
    // 7 MiB (7.3 MB): too little for two threads' grid operators (7.5 MB), or for 30 cells in
    // coefficient space (61 MB) beside the rows they are compressed from; with a viscosity
    // contrast, 13 MiB (13.6 MB) do not hold two threads' two grid operators (15.1 MB), but one
    // cell's two compressed ones (4.1 MB) and each thread's rows (7.5 MB) fit.
    assert_eq!(
        OperatorStorage::for_budget(30, 2, 12, 1, 7 * mib),
        OperatorStorage::MatrixFree
    );
    assert_eq!(
        OperatorStorage::for_budget(1, 2, 12, 2, 13 * mib),
        OperatorStorage::Coefficients
    );
    assert_eq!(OperatorStorage::Grid.bytes_per_cell(12, 1), 0);
    assert_eq!(
        OperatorStorage::Grid.bytes_per_thread(12, 2),
        2 * 9 * 312 * 168 * 8
    );
    assert_eq!(
        OperatorStorage::Coefficients.bytes_per_cell(12, 1),
        9 * 168 * 168 * 8
    );
    assert_eq!(s.output_every, 4);
    let on = |name: &str| s.effects.iter().find(|e| e.name == name).unwrap().enabled;
    assert!(
        on("fmm")
            && on("double_layer")
            && on("skalak")
            && on("background_flow")
            && on("body_force")
    );
    // RBC bounding radius: α · radius with α = 1.3858 (unit equivalent radius).
    assert!(
        (s.cells[0].bounding_radius / 1.5 - 1.3858).abs() < 2e-3,
        "{}",
        s.cells[0].bounding_radius
    );
}

#[test]
fn one_plain_cell_builds_only_what_it_needs() {
    let s = parse(file(), "[[cells]]\nshape = \"sphere\"\n").unwrap();
    assert_eq!(s.cells.len(), 1);
    assert_eq!(s.flow, Flow::None);
    assert_eq!(s.numerics.order, 12);
    for e in &s.effects {
        assert!(!e.enabled, "{} enabled: {}", e.name, e.reason);
        assert!(!e.reason.is_empty());
    }
    let fmm = s.effects.iter().find(|e| e.name == "fmm").unwrap();
    assert!(fmm.reason.contains("one cell"), "{}", fmm.reason);
}

/// `[numerics] grid`: by default the grid of a cell with shear elasticity follows its material
/// points and a vesicle's is relaxed after every step; "relaxed" and "material" reach every
/// cell's stepper, and the summary's effects say which cells follow the material.
#[test]
fn grid_motion_reaches_every_cell() {
    let two = |grid: &str| {
        format!(
            "[[cells]]\nshape = \"rbc\"\nshear_modulus = 1.0\n\n[[cells]]\nshape = \
             \"sphere\"\ncenter = [4.0, 0, 0]\n\n[[cells]]\nshape = \"sphere\"\nmembrane = \
             \"capsule\"\nshear_modulus = 1.0\ncenter = [8.0, 0, 0]\n[numerics]\norder = 8\n{grid}"
        )
    };
    for (grid, relaxed, followed) in [
        ("", [false, true, false], "0, 2"),
        ("grid = \"auto\"\n", [false, true, false], "0, 2"),
        ("grid = \"relaxed\"\n", [true, true, false], "2"),
        ("grid = \"material\"\n", [false, false, false], "0, 1, 2"),
    ] {
        let s = parse(file(), &two(grid)).unwrap();
        let susp = mobo::run::assembly::build(&s).unwrap();
        let got: Vec<bool> = susp
            .steppers()
            .iter()
            .map(|c| c.params().reparametrize.is_some())
            .collect();
        assert_eq!(got, relaxed, "{grid}");
        let e = s
            .effects
            .iter()
            .find(|e| e.name == "material_grid")
            .unwrap();
        assert!(e.enabled, "{grid}");
        assert!(
            e.reason.contains(&format!("on cells {followed} (")),
            "{grid}: {}",
            e.reason
        );
    }
    // One vesicle: nothing follows the material.
    let s = parse(file(), "[[cells]]\nshape = \"sphere\"\n").unwrap();
    let e = s
        .effects
        .iter()
        .find(|e| e.name == "material_grid")
        .unwrap();
    assert!(
        !e.enabled && e.reason.contains("relaxed after every step"),
        "{}",
        e.reason
    );
}

#[test]
fn surfaces_are_scaled_rotated_and_placed() {
    let s = parse(file(), FULL).unwrap();
    let mut calc = SurfaceCalculus::new(8).unwrap();
    // RBC: equivalent radius 1.5 at the origin.
    let g = calc
        .geometry(s.cells[0].surface(8).unwrap().coefs())
        .unwrap();
    let v = g.volume();
    assert!(
        (v - 4.0 / 3.0 * std::f64::consts::PI * 1.5f64.powi(3)).abs() < 1e-6 * v,
        "{v}"
    );
    // Ellipsoid turned by 90° about z: its longest axis lies along y, centred at (6, 0, 0).
    let g = calc
        .geometry(s.cells[1].surface(8).unwrap().coefs())
        .unwrap();
    let c = g.centroid();
    assert!(
        (c[0] - 6.0).abs() < 1e-10 && c[1].abs() < 1e-10 && c[2].abs() < 1e-10,
        "{c:?}"
    );
    let (_, axes) = g.principal_axes();
    assert!(axes[0][1].abs() > 1.0 - 1e-8, "{axes:?}");
}

#[test]
fn many_cells_on_a_lattice_and_at_random_do_not_overlap() {
    let lat = parse(
        file(),
        "[[cells]]\nshape = \"rbc\"\ncount = 10\nplacement = \"lattice\"\n",
    )
    .unwrap();
    assert_eq!(lat.cells.len(), 10);
    let rnd = parse(
        file(),
        "[[cells]]\nshape = \"sphere\"\ncount = 40\nplacement = \"random\"\nregion = [[0, 0, 0], [12, 12, 12]]\nseed = 3\n",
    )
    .unwrap();
    assert_eq!(rnd.cells.len(), 40);
    for s in [&lat, &rnd] {
        for i in 0..s.cells.len() {
            for j in 0..i {
                let (a, b) = (s.cells[i].center, s.cells[j].center);
                let d =
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
                assert!(d >= s.cells[i].bounding_radius + s.cells[j].bounding_radius);
            }
        }
    }
    for c in &rnd.cells {
        assert!(
            c.center.iter().all(|&x| (1.0..=11.0).contains(&x)),
            "{:?}",
            c.center
        );
    }
    let again = parse(
        file(),
        "[[cells]]\nshape = \"sphere\"\ncount = 40\nplacement = \"random\"\nregion = [[0, 0, 0], [12, 12, 12]]\nseed = 3\n",
    )
    .unwrap();
    assert_eq!(rnd, again, "same seed, same placement");
}

#[test]
fn gpu_setting_is_auto_true_or_false() {
    use mobo::gpu::GpuChoice;
    let base = "[[cells]]\nshape = \"sphere\"\n";
    assert_eq!(parse(file(), base).unwrap().numerics.gpu, GpuChoice::Auto);
    for (v, want) in [
        ("\"auto\"", GpuChoice::Auto),
        ("true", GpuChoice::On),
        ("false", GpuChoice::Off),
    ] {
        let text = format!("{base}[numerics]\ngpu = {v}\n");
        assert_eq!(parse(file(), &text).unwrap().numerics.gpu, want, "{v}");
    }
}

#[test]
fn walls_are_split_over_ranks_when_asked_or_when_too_big_to_replicate() {
    use mobo::scene::cells::WALL_SPLIT_BYTES;
    let (small, big) = (WALL_SPLIT_BYTES / 2, WALL_SPLIT_BYTES + 1);
    // 64 GB free: 16 ranks' copies of half a GiB (twice that while factoring) fit in 60 % of
    // it, 64 ranks' do not.
    let free = Some(64_000_000_000);
    for (how, ranks, bytes, available, splits) in [
        (WallSolve::Auto, 2, small, None, false),
        (WallSolve::Auto, 2, big, None, true),
        (WallSolve::Auto, 1, big, None, false),
        (WallSolve::Auto, 16, small, free, false),
        (WallSolve::Auto, 64, small, free, true),
        (WallSolve::Split, 2, small, None, true),
        (WallSolve::Split, 1, small, None, false),
        (WallSolve::Replicated, 64, big, free, false),
    ] {
        assert_eq!(
            how.splits(ranks, bytes, available),
            splits,
            "{how:?} {ranks} {bytes}"
        );
    }
}

#[test]
fn bad_scenes_name_the_file_the_line_and_the_problem() {
    let cases: &[(&str, &str)] = &[
        ("[[cells]]\nshape = \"sphere\"\ncolour = 1\n", "scene.toml:3"),
        ("[[cells]]\nshape = \"sphere\"\nradius = \"big\"\n", "scene.toml:3"),
        ("[[cells]]\nshape = \"sphere\"\nradius = -1.0\n", "radius must be a positive"),
        ("[[cells]]\nshape = \"cube\"\n", "unknown shape \"cube\""),
        ("[[cells]]\nshape = \"ellipsoid\"\n", "needs axes"),
        ("[[cells]]\nshape = \"prolate\"\nreduced_volume = 1.5\n", "reduced_volume must be in (0, 1)"),
        (
            "[[cells]]\nshape = \"sphere\"\n\n[[cells]]\nshape = \"sphere\"\ncenter = [1.0, 0, 0]\n",
            "overlap",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\ncount = 50\nplacement = \"random\"\nregion = [[0, 0, 0], [4, 4, 4]]\n",
            "could only place",
        ),
        ("[[cells]]\nshape = \"sphere\"\n[numerics]\ngmres_tol = 2.0\n", "scene.toml:4"),
        ("[[cells]]\nshape = \"sphere\"\n[numerics]\norder = 1\n", "order must be between"),
        ("[[cells]]\nshape = \"sphere\"\n[numerics]\nscheme = \"rk4\"\n", "unknown scheme"),
        (
            "[[cells]]\nshape = \"sphere\"\n[numerics]\noperator_storage = \"sparse\"\n",
            "scene.toml:4:20: [numerics] operator_storage: unknown storage \"sparse\"",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\n[numerics]\ngpu = \"sometimes\"\n",
            "scene.toml:4:7: [numerics] gpu must be \"auto\", true or false, got \"sometimes\"",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\n[numerics]\ngrid = \"sideways\"\n",
            "scene.toml:4:8: [numerics] grid: unknown choice \"sideways\" (auto, relaxed, material)",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\n[numerics]\nwall_solve = \"halved\"\n",
            "scene.toml:4:14: [numerics] wall_solve: unknown choice \"halved\" (auto, replicated, split)",
        ),
        ("[[cells]]\nshape = \"sphere\"\n[flow]\nkind = \"shear\"\n", "needs rate"),
        ("[[cells]]\nshape = \"sphere\"\n[flow]\nkind = \"vortex\"\nrate = 1.0\n", "unknown flow"),
        ("[[cells]]\nshape = \"sphere\"\n[output]\nevery = 0\n", "every must be at least 1"),
        ("[fluid]\nviscosity = 1.0\n", "no [[cells]]"),
        ("[[cells]]\nshape = \"sphere\"\norientation = [0, 0, 0, 30]\n", "non-zero axis"),
        // Keys that would be ignored are refused.
        (
            "[[cells]]\nshape = \"rbc\"\n[numerics]\norder = 2\n",
            "order = 2 cannot hold the red blood cell",
        ),
        (
            "[[cells]]\nshape = \"rbc\"\nreduced_volume = 0.6\n",
            "reduced_volume applies to shape = \"prolate\" or \"oblate\" only",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\naxes = [1, 2, 3]\n",
            "axes applies to shape = \"ellipsoid\" only",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\ncount = 8\nplacement = \"lattice\"\nregion = [[0, 0, 0], [9, 9, 9]]\n",
            "region applies to placement = \"random\" only",
        ),
    ];
    for (text, want) in cases {
        let e = parse(file(), text).expect_err(text).to_string();
        assert!(e.starts_with("scene.toml"), "{e}");
        assert!(
            e.contains(want),
            "expected '{want}' in: {e}\n--- scene:\n{text}"
        );
    }
    // Value errors carry the line of the value.
    let e = parse(file(), "[[cells]]\nshape = \"sphere\"\nradius = -1.0\n").unwrap_err();
    assert_eq!(e.place.map(|p| p.0), Some(3));
}

/// Two `[[cells]]` groups placed at random in the same region: the second keeps clear of the
/// first (a user's mixed suspension), and a region asked to hold too much says how much.
#[test]
fn random_groups_in_one_region_do_not_overlap() {
    let text = r#"
[[cells]]
shape = "rbc"
count = 12
placement = "random"
region = [[0, 0, 0], [9, 9, 9]]
seed = 3

[[cells]]
shape = "sphere"
radius = 0.8
count = 12
placement = "random"
region = [[0, 0, 0], [9, 9, 9]]
seed = 3
"#;
    let scene = parse(file(), text).expect("two random groups fit in a 9³ region");
    assert_eq!(scene.cells.len(), 24);
    // Independent check of every pair's bounding spheres (the parser's own check aside).
    for (i, a) in scene.cells.iter().enumerate() {
        for b in &scene.cells[..i] {
            let d = (0..3)
                .map(|k| (a.center[k] - b.center[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(
                d >= a.bounding_radius + b.bounding_radius,
                "cells overlap: {d}"
            );
        }
    }
    // A third group asking for more than the region has left.
    let crowded = format!(
        "{text}\n[[cells]]\nshape = \"sphere\"\ncount = 80\nplacement = \"random\"\nregion = [[0, 0, 0], [9, 9, 9]]\n"
    );
    let e = parse(file(), &crowded)
        .expect_err("the region is too full")
        .to_string();
    assert!(e.contains("could only place"), "{e}");
    assert!(e.contains("of 80 cells"), "{e}");
    assert!(e.contains("volume fraction of"), "{e}");
    assert!(e.contains("earlier [[cells]] entries already take"), "{e}");
}

/// Scenes written in code (`scene::spec::SceneSpec`) and scene files are the same thing: every
/// example scene and the full scene above read as a spec, written back and read again are
/// unchanged, and the spec validates to the scene the file parses to (up to the line numbers of
/// cells and walls, which a spec has not); bad values give the file's own messages, without a place.
#[test]
fn specs_and_files_describe_the_same_scenes() {
    use mobo::scene::spec::{CellGroupSpec, SceneSpec, ShapeKind};
    let strip = |mut s: mobo::scene::cells::CellScene| {
        for c in &mut s.cells {
            c.line = 0;
        }
        for w in &mut s.walls {
            w.line = 0;
            // Where a grid wall's file names were in the text.
            w.files.clear();
        }
        if let Some(p) = &mut s.plane {
            p.line = 0;
        }
        s
    };
    let mut texts = vec![("full".to_string(), FULL.to_string())];
    for e in std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/scenes")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let mut text = std::fs::read_to_string(&p).unwrap();
        // A grid wall's files named from the examples' folder, which the spec (whose relative
        // names start from the working directory) and the file read alike.
        let folder = p.parent().unwrap().display().to_string();
        for key in ["positions", "velocity"] {
            text = text.replace(&format!("{key} = \""), &format!("{key} = \"{folder}/"));
        }
        // Cell scenes only (the Brownian and DPD scenes have other schemas).
        if text.contains("[[cells]]") {
            texts.push((p.display().to_string(), text));
        }
    }
    assert!(texts.len() >= 4, "{}", texts.len());
    for grid in ["auto", "relaxed", "material"] {
        texts.push((
            format!("grid = {grid}"),
            format!("[[cells]]\nshape = \"sphere\"\n[numerics]\ngrid = \"{grid}\"\n"),
        ));
    }
    texts.push((
        "velocity_plane".to_string(),
        "[[cells]]\nshape = \"sphere\"\n[output]\nvelocity_plane = { origin = [-2.0, -2.0, 0.0], \
         u = [4.0, 0.0, 0.0], v = [0.0, 4.0, 0.5], points = [5, 7] }\n"
            .to_string(),
    ));
    for gpu in ["\"auto\"", "true", "false"] {
        texts.push((
            format!("gpu = {gpu}"),
            format!("[[cells]]\nshape = \"sphere\"\n[numerics]\ngpu = {gpu}\n"),
        ));
    }
    for (name, text) in &texts {
        let spec = SceneSpec::from_toml(text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let again = SceneSpec::from_toml(&spec.to_toml().unwrap()).unwrap();
        assert_eq!(again, spec, "{name}: round trip");
        let from_file = parse(file(), text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let from_spec = spec.build().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(strip(from_spec), strip(from_file), "{name}: built scene");
    }
    // Bad values: the message of the file, without a line.
    let bad = SceneSpec {
        cells: vec![CellGroupSpec {
            radius: Some(-1.0),
            ..CellGroupSpec::new(ShapeKind::Sphere)
        }],
        ..Default::default()
    };
    let e = bad.build().unwrap_err();
    assert!(e.place.is_none());
    let from_file = parse(file(), "[[cells]]\nshape = \"sphere\"\nradius = -1.0\n").unwrap_err();
    // The same check and words, the key named as the spec's field.
    assert!(
        from_file.message.contains("[[cells]] #1 radius"),
        "{from_file}"
    );
    assert_eq!(
        e.message,
        from_file
            .message
            .replace("[[cells]] #1 radius", "cells[0].radius")
    );
    // Cells of a spec are cited as its entries, never by a line of the text it wrote.
    let mut close = SceneSpec {
        cells: vec![CellGroupSpec::new(ShapeKind::Sphere); 2],
        ..Default::default()
    };
    close.cells[1].center = Some([0.5, 0.0, 0.0]);
    let e = close.build().unwrap_err().to_string();
    assert!(
        e.contains("overlap") && e.contains("cells[1] of the spec") && !e.contains("line"),
        "{e}"
    );
    let none = SceneSpec::default().build().unwrap_err();
    assert!(none.to_string().contains("no [[cells]]"), "{none}");
}

/// A scene in SI units (`[units] system = "SI"`) is the dimensionless scene a user would write
/// by hand: lengths over the first cells' radius `a`, moduli over their shear modulus `G`,
/// times over `μa/G`, forces over `Ga`, energies over `Ga²`.
#[test]
fn a_scene_in_si_units_is_the_hand_made_dimensionless_scene() {
    let (a, mu, g, kappa, rate) = (2.8e-6, 1.2e-3, 6e-6, 2e-19, 100.0);
    let t = mu * a / g;
    let si = format!(
        r#"
[units]
system = "SI"
[fluid]
viscosity = {mu}
[flow]
kind = "shear"
rate = {rate}
[[cells]]
shape = "rbc"
radius = {a}
center = [0.0, 0.0, 0.0]
shear_modulus = {g}
bending_modulus = {kappa}
viscosity_ratio = 5.0
[[cells]]
shape = "sphere"
radius = {}
center = [{}, 0.0, 0.0]
bending_modulus = {}
force = [{}, 0.0, 0.0]
[[walls]]
kind = "container"
shape = "sphere"
radius = {}
[numerics]
order = 6
dt = {}
t_end = {}
contact_distance = {}
[output]
velocity_plane = {{ origin = [{}, 0.0, 0.0], u = [{}, 0.0, 0.0], v = [0.0, {}, 0.0], points = [3, 3] }}
"#,
        0.5 * a,
        4.0 * a,
        3.0 * kappa,
        2.0 * g * a,
        9.0 * a,
        0.01 * t,
        0.5 * t,
        0.05 * a,
        -3.0 * a,
        6.0 * a,
        2.0 * a,
    );
    let by_hand = format!(
        r#"
[fluid]
viscosity = 1.0
[flow]
kind = "shear"
rate = {}
[[cells]]
shape = "rbc"
radius = 1.0
center = [0.0, 0.0, 0.0]
shear_modulus = 1.0
bending_modulus = {}
viscosity_ratio = 5.0
[[cells]]
shape = "sphere"
radius = 0.5
center = [4.0, 0.0, 0.0]
bending_modulus = {}
force = [2.0, 0.0, 0.0]
[[walls]]
kind = "container"
shape = "sphere"
radius = 9.0
[numerics]
order = 6
dt = 0.01
t_end = 0.5
contact_distance = 0.05
[output]
velocity_plane = {{ origin = [-3.0, 0.0, 0.0], u = [6.0, 0.0, 0.0], v = [0.0, 2.0, 0.0], points = [3, 3] }}
"#,
        rate * t,
        kappa / (g * a * a),
        3.0 * kappa / (g * a * a),
    );
    let got = parse(file(), &si).unwrap();
    let want = parse(file(), &by_hand).unwrap();
    let close = |x: f64, y: f64, what: &str| {
        assert!(
            (x - y).abs() <= 1e-12 * y.abs().max(1e-300),
            "{what}: {x} against {y}"
        )
    };
    close(got.viscosity, want.viscosity, "viscosity");
    close(got.flow.rate_scale(), want.flow.rate_scale(), "shear rate");
    close(got.numerics.dt, want.numerics.dt, "dt");
    close(got.numerics.t_end, want.numerics.t_end, "t_end");
    close(
        got.numerics.contact_distance.unwrap(),
        want.numerics.contact_distance.unwrap(),
        "contact_distance",
    );
    for (c, w) in got.cells.iter().zip(&want.cells) {
        close(c.radius, w.radius, "radius");
        close(
            c.shear_modulus.max(1e-300),
            w.shear_modulus.max(1e-300),
            "G",
        );
        close(c.bending_modulus, w.bending_modulus, "κ");
        for k in 0..3 {
            assert!((c.center[k] - w.center[k]).abs() < 1e-12, "center");
            assert!((c.force[k] - w.force[k]).abs() < 1e-12, "force");
        }
    }
    match (&got.walls[0].shape, &want.walls[0].shape) {
        (
            &mobo::scene::walls::WallShape::Sphere { radius: x },
            &mobo::scene::walls::WallShape::Sphere { radius: y },
        ) => close(x, y, "wall radius"),
        other => panic!("{other:?}"),
    }
    let (gp, wp) = (
        got.output.velocity_plane.unwrap(),
        want.output.velocity_plane.unwrap(),
    );
    for (x, y) in gp.sample_points().iter().zip(wp.sample_points()) {
        for k in 0..3 {
            assert!(
                (x[k] - y[k]).abs() < 1e-12,
                "velocity plane {x:?} against {y:?}"
            );
        }
    }
    // The scales, and the groups of the first cells.
    let u = got.units.expect("SI scales");
    assert!(want.units.is_none());
    close(u.length_m, a, "length scale");
    close(u.time_s, t, "time scale");
    close(u.force_n(), g * a, "force scale");
    let groups = got.groups().unwrap();
    close(groups.capillary_number.unwrap(), mu * rate * a / g, "Ca");
    close(
        groups.reduced_bending.unwrap(),
        kappa / (g * a * a),
        "reduced bending",
    );
    let by_hand = want.groups().unwrap();
    close(groups.rate, by_hand.rate, "rate");
    close(
        groups.bending_capillary_number.unwrap(),
        by_hand.bending_capillary_number.unwrap(),
        "bending capillary number",
    );
    assert!(got
        .effects
        .iter()
        .any(|e| e.name == "units" && e.reason.contains("5.6000e-4 s")));
    // Bad units are refused with the place and the reason.
    for (text, line, needle) in [
        (
            si.replace("system = \"SI\"", "system = \"cgs\""),
            3,
            "must be \"SI\"",
        ),
        (
            si.replace("[fluid]\nviscosity = 0.0012\n", ""),
            3,
            "needs [fluid] viscosity",
        ),
        (
            si.replacen("radius = 0.0000028\n", "", 1),
            10,
            "needs a positive radius",
        ),
        (
            si.replacen(
                "shear_modulus = 0.000006\nbending_modulus = 0.0000000000000000002\n",
                "",
                1,
            ),
            10,
            "shear_modulus (N/m) or bending_modulus (J)",
        ),
    ] {
        let e = parse(file(), &text).unwrap_err().to_string();
        assert!(
            e.contains(&format!(":{line}:")) && e.contains(needle),
            "{needle}: {e}"
        );
    }
}
