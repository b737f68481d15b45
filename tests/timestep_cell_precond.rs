//! The preconditioner from the cell itself (`timestep::cell_preconditioner`): exact for an
//! operator of the step's structure (checked against the operator itself), the same step as
//! with the sphere's preconditioner (to the GMRES tolerance) in far fewer iterations, whatever
//! the shape, and a run that uses it resumes bit for bit (its record travels in the checkpoint).

mod common;

use common::{frame_bits, mobo, ok, rotation, stop_and_resume, summary, tmpdir, write};
use mobo::sph_harmonics::ShTransform;
use mobo::timestep::cell_preconditioner::{CellPreconditioner, CellPreconditionerScratch};
use mobo::timestep::coupling::CouplingParams;
use mobo::timestep::grid_frame::relative_rotation;
use mobo::timestep::semi_implicit::{OperatorStorage, Preconditioning, TimeScheme, VesicleParams};
use mobo::timestep::suspension::{CellSetup, Suspension};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::{FnOperator, GmresParams};
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes::{self, Spheroid};

/// A deterministic pseudo-random sequence in [-0.5, 0.5).
fn noise(seed: u64, len: usize) -> Vec<f64> {
    let mut s = seed;
    (0..len)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            f64::from_bits((s >> 12) | 0x3ff0_0000_0000_0000) - 1.5
        })
        .collect()
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// An operator of the step's structure on `[X; σ]`: `A z = E z + G F z` with `E = diag(a I,
/// 0)` (what the grid complement sees) and `G` a dense `4n × 4n_c` map whose tension rows are
/// band-limited (`F⁻¹ H_σ`) and whose position rows are band-limited too (`band_limited`) or
/// arbitrary grid functions (the single layer's content above degree `p`).
struct Structured {
    sht: ShTransform,
    a: f64,
    /// `G`, column-major `4n × 4n_c`.
    g: Vec<f64>,
}

impl Structured {
    fn new(p: usize, a: f64, band_limited: bool, seed: u64) -> Self {
        let sht = ShTransform::new(p).unwrap();
        let (n, nc) = (sht.n_points(), sht.n_coefs());
        let m = 4 * nc;
        let mut ws = sht.workspace();
        // H = 2 I + 0.3 R / √m: well conditioned.
        let r = noise(seed, m * m);
        let mut h = vec![0.0; m * m];
        for j in 0..m {
            for i in 0..m {
                h[j * m + i] =
                    0.3 * r[j * m + i] / (m as f64).sqrt() + if i == j { 2.0 } else { 0.0 };
            }
        }
        let mut g = vec![0.0; 4 * n * m];
        sht.inverse(&h, &mut g, &mut ws).unwrap();
        if !band_limited {
            // Position rows: add grid noise (content outside the coefficient space).
            let extra = noise(seed + 1, 4 * n * m);
            for j in 0..m {
                for i in 0..3 * n {
                    g[j * 4 * n + i] += 0.2 * extra[j * 4 * n + i];
                }
            }
        }
        Structured { sht, a, g }
    }

    fn apply(&self, z: &[f64], y: &mut [f64]) {
        let (n, nc) = (self.sht.n_points(), self.sht.n_coefs());
        let m = 4 * nc;
        let mut ws = self.sht.workspace();
        let mut c = vec![0.0; m];
        self.sht.forward(z, &mut c, &mut ws).unwrap();
        for i in 0..4 * n {
            let e = if i < 3 * n { self.a * z[i] } else { 0.0 };
            y[i] = e + (0..m).map(|j| self.g[j * 4 * n + i] * c[j]).sum::<f64>();
        }
    }
}

/// `A M⁻¹ v` for the structured operator and its cell preconditioner.
fn a_minv(
    s: &Structured,
    pc: &CellPreconditioner,
    scratch: &mut CellPreconditionerScratch,
    v: &[f64],
) -> Vec<f64> {
    let mut z = vec![0.0; v.len()];
    pc.apply_with(&s.sht, scratch, v, &mut z).unwrap();
    let mut y = vec![0.0; v.len()];
    s.apply(&z, &mut y);
    y
}

/// A vector whose tension part is band-limited (the range the tension rows can reach).
fn test_vector(sht: &ShTransform, seed: u64) -> Vec<f64> {
    let (n, nc) = (sht.n_points(), sht.n_coefs());
    let mut v = noise(seed, 4 * n);
    let mut ws = sht.workspace();
    let mut c = vec![0.0; nc];
    sht.forward(&v[3 * n..], &mut c, &mut ws).unwrap();
    sht.inverse(&c, &mut v[3 * n..], &mut ws).unwrap();
    v
}

#[test]
fn the_inverse_is_exact_for_an_operator_of_the_steps_structure() {
    for p in [4, 6] {
        let s = Structured::new(p, 0.7, true, 11 + p as u64);
        let n = s.sht.n_points();
        let op = FnOperator::new(4 * n, |z: &[f64], y: &mut [f64]| s.apply(z, y));
        let pc = CellPreconditioner::build(&op, &s.sht, s.a).unwrap();
        assert!(pc.pivot_ratio() > 1e-3, "p = {p}: {}", pc.pivot_ratio());
        let mut scratch = CellPreconditionerScratch::new(&s.sht);
        for seed in 0..3 {
            let v = test_vector(&s.sht, 100 + seed);
            let y = a_minv(&s, &pc, &mut scratch, &v);
            let err: Vec<f64> = y.iter().zip(&v).map(|(a, b)| a - b).collect();
            let rel = norm(&err) / norm(&v);
            // Rounding of an order-4n_c LU and four transforms.
            let tol = 1e3 * f64::EPSILON * (4 * n) as f64;
            assert!(
                rel < tol,
                "p = {p}: |A M⁻¹ v − v|/|v| = {rel:.2e} (tol {tol:.1e})"
            );
        }
    }
}

#[test]
fn with_content_above_degree_p_the_error_is_nilpotent() {
    // A M⁻¹ = I + N with N mapping into the grid complement and N² = 0: GMRES needs at most
    // two iterations at the step the preconditioner is built for.
    let s = Structured::new(6, 1.3, false, 5);
    let n = s.sht.n_points();
    let op = FnOperator::new(4 * n, |z: &[f64], y: &mut [f64]| s.apply(z, y));
    let pc = CellPreconditioner::build(&op, &s.sht, s.a).unwrap();
    let mut scratch = CellPreconditionerScratch::new(&s.sht);
    let v = test_vector(&s.sht, 9);
    let nv: Vec<f64> = a_minv(&s, &pc, &mut scratch, &v)
        .iter()
        .zip(&v)
        .map(|(a, b)| a - b)
        .collect();
    assert!(norm(&nv) > 1e-3 * norm(&v), "N is not trivial here");
    let nnv: Vec<f64> = a_minv(&s, &pc, &mut scratch, &nv)
        .iter()
        .zip(&nv)
        .map(|(a, b)| a - b)
        .collect();
    let rel = norm(&nnv) / norm(&nv);
    assert!(rel < 1e-11, "|N² v|/|N v| = {rel:.2e}");
}

#[test]
fn wrong_sizes_are_errors_not_panics() {
    let sht = ShTransform::new(4).unwrap();
    let n = sht.n_points();
    let op = FnOperator::new(4 * n + 1, |_: &[f64], y: &mut [f64]| y.fill(0.0));
    assert!(CellPreconditioner::build(&op, &sht, 1.0).is_err());
    let op = FnOperator::new(4 * n, |z: &[f64], y: &mut [f64]| y.copy_from_slice(z));
    assert!(CellPreconditioner::build(&op, &sht, 0.0).is_err());
    // The identity: its coefficient-space block is the identity, invertible.
    let pc = CellPreconditioner::build(&op, &sht, 1.0).unwrap();
    let mut scratch = CellPreconditionerScratch::new(&sht);
    let mut z = vec![0.0; 4 * n];
    assert!(pc
        .apply_with(&sht, &mut scratch, &[0.0; 3], &mut z)
        .is_err());
    // A singular operator (zero) is refused with the pivot ratio.
    let zero = FnOperator::new(4 * n, |_: &[f64], y: &mut [f64]| y.fill(0.0));
    let e = CellPreconditioner::build(&zero, &sht, 1.0).err().unwrap();
    assert!(e.to_string().contains("singular"), "{e}");
}

fn params(p: usize) -> VesicleParams {
    VesicleParams {
        bending_modulus: 0.05,
        viscosity: 1.0,
        force: [0.0; 3],
        dt: 0.02,
        upsampled_order: 2 * p,
        gmres: GmresParams::default(),
        correct_drift: true,
        reparametrize: Some(ReparamParams::default()),
        preconditioner: true,
        scheme: TimeScheme::Euler,
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    }
}

/// `steps` steps of `surface` in shear with `preconditioning`, viscosity ratio `lambda` and
/// operator `storage`: the iterations of each step, the final coefficients and the own
/// preconditioners built.
fn run(
    p: usize,
    surface: &[f64],
    (lambda, storage): (f64, OperatorStorage),
    preconditioning: Preconditioning,
    steps: usize,
) -> (Vec<usize>, Vec<f64>, usize) {
    let mut st = VesicleStepper::new(
        p,
        VesicleParams {
            viscosity_ratio: lambda,
            ..params(p)
        },
    )
    .unwrap();
    st.set_preconditioning(preconditioning);
    st.set_operator_storage(storage);
    let mut c = surface.to_vec();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let its = (0..steps)
        .map(|_| st.step(&mut c, &shear).unwrap().gmres.iterations)
        .collect();
    (its, c, st.own_preconditioner_builds())
}

#[test]
fn the_same_steps_in_fewer_iterations_for_non_spherical_cells() {
    let p = 8;
    let steps = 12;
    let rbc = shapes::rbc(p).unwrap();
    let prolate = shapes::reduced_volume_spheroid(p, 0.85, Spheroid::Prolate, 1.0).unwrap();
    for (name, surface, setup) in [
        ("RBC", &rbc, (1.0, OperatorStorage::Grid)),
        ("prolate 0.85", &prolate, (1.0, OperatorStorage::Grid)),
        // The double layer in the operator, the operators stored in coefficient space.
        (
            "prolate 0.85, λ = 5",
            &prolate,
            (5.0, OperatorStorage::Coefficients),
        ),
    ] {
        let (sphere_its, sphere_c, none) =
            run(p, surface.coefs(), setup, Preconditioning::Sphere, steps);
        assert_eq!(none, 0);
        let (cell_its, cell_c, builds) =
            run(p, surface.coefs(), setup, Preconditioning::CELL, steps);
        // Built from the first step's own operator: exact up to the content above degree p.
        assert!(cell_its[0] <= 2, "{name}: first step {cell_its:?}");
        let mean = |v: &[usize]| v.iter().sum::<usize>() as f64 / v.len() as f64;
        println!(
            "{name}: iterations per step, sphere {:.1} (max {}), cell {:.1} (max {}), {builds} builds",
            mean(&sphere_its),
            sphere_its.iter().max().unwrap(),
            mean(&cell_its),
            cell_its.iter().max().unwrap()
        );
        // Rebuilt after a step of more than 8: no step far beyond that.
        assert!(cell_its.iter().all(|&i| i <= 12), "{name}: {cell_its:?}");
        assert!(
            mean(&cell_its) < 0.5 * mean(&sphere_its),
            "{name}: cell {cell_its:?} against sphere {sphere_its:?}"
        );
        assert!(builds >= 1 && builds < steps, "{name}: {builds} builds");
        // The same steps, to the GMRES tolerance (1e-8) carried through 12 steps.
        let diff: Vec<f64> = cell_c.iter().zip(&sphere_c).map(|(a, b)| a - b).collect();
        let rel = norm(&diff) / norm(&sphere_c);
        assert!(rel < 1e-6, "{name}: surfaces differ by {rel:.2e}");
    }
}

/// Two cells in shear: an RBC with Skalak elasticity stepped linearly implicitly (the
/// Jacobian is in its own operator) and a prolate vesicle, BDF2 (the first step's Euler `τ`
/// differs), the own preconditioner rebuilt after a step of more than 3 iterations.
const TWO_CELLS: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
radius = 1.0
shear_modulus = 0.3
bending_modulus = 0.1
center = [-1.9, 0.5, 0.0]
[[cells]]
shape = "prolate"
reduced_volume = 0.85
bending_modulus = 0.1
center = [1.9, -0.5, 0.0]
[numerics]
order = 6
dt = 0.04
t_end = 0.48
scheme = "bdf2"
elasticity = "implicit"
preconditioner = "cell"
preconditioner_rebuild_after = 3
[output]
every = 3
vtk = false
"#;

#[test]
fn a_run_with_own_preconditioners_resumes_bit_for_bit() {
    let dir = tmpdir("cell-precond-resume");
    let scene = write(&dir, "two.toml", TWO_CELLS);
    let full = dir.join("full");
    let o = mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]);
    ok(&o, "full run");
    let s = summary(&full);
    assert_eq!(s["steps"].as_u64(), Some(12));
    let builds = s["counters"]["preconditioner_builds"].as_u64().unwrap();
    assert!(
        (3..24).contains(&builds),
        "built at the first step, for BDF2's τ and when stale, not every step: {builds}"
    );
    let its = s["gmres_iterations_mean"].as_f64().unwrap();
    assert!(its < 6.0, "mean iterations {its}");
    let want = frame_bits(&full, true);
    // Stopped at two steps, then resumed: the cells hold preconditioners built earlier, which
    // the resumed run rebuilds from their records (the test fails without them: checked).
    for stop in [4, 7] {
        let part = dir.join(format!("part{stop}"));
        stop_and_resume(&scene, &part, stop);
        assert_eq!(
            frame_bits(&part, true),
            want,
            "stop at {stop} + resume = one run, bit for bit"
        );
    }
}

#[test]
fn an_unknown_preconditioner_is_a_located_error() {
    let dir = tmpdir("cell-precond-errors");
    for (bad, key, what) in [
        (
            "preconditioner = \"cel\"",
            "preconditioner =",
            "unknown preconditioner \"cel\" (sphere, cell)",
        ),
        (
            "preconditioner = \"cell\"\npreconditioner_rebuild_after = 0",
            "preconditioner_rebuild_after",
            "must be from 1 to 1000000 (iterations), got 0",
        ),
        (
            "preconditioner = \"sphere\"\npreconditioner_rebuild_after = 4",
            "preconditioner_rebuild_after",
            "applies to preconditioner = \"cell\" only",
        ),
    ] {
        let text = TWO_CELLS.replace(
            "preconditioner = \"cell\"\npreconditioner_rebuild_after = 3",
            bad,
        );
        let scene = write(&dir, "bad.toml", &text);
        let o = mobo(&[
            "run",
            &scene,
            "--out",
            dir.join("out").to_str().unwrap(),
            "--quiet",
        ]);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("bad.toml") && err.contains(what), "{err}");
        let line = 1 + text.lines().position(|l| l.starts_with(key)).unwrap();
        assert!(
            err.contains(&format!("bad.toml:{line}:")),
            "line {line}: {err}"
        );
    }
}

#[test]
fn the_relative_rotation_turns_the_build_frame_into_the_current_one() {
    let rot = |axis: [f64; 3], deg: f64| {
        let n = norm(&axis);
        rotation(axis.map(|v| v / n), deg.to_radians())
    };
    let (r, s) = (rot([1.0, 2.0, -0.5], 37.0), rot([0.3, -1.0, 0.8], -64.0));
    let t = relative_rotation(&r, &s);
    for a in 0..3 {
        for b in 0..3 {
            let ts: f64 = (0..3).map(|k| t[a][k] * s[k][b]).sum();
            assert!(
                (ts - r[a][b]).abs() < 1e-14,
                "(T S)[{a}][{b}] = {ts}, R = {}",
                r[a][b]
            );
        }
    }
}

#[test]
fn a_cell_turned_with_its_grid_keeps_its_preconditioner_exact() {
    // Built for an RBC whose shape and grid are turned by A (so the grid's frame at the build is
    // A, not the identity), then used for the same cell turned again by T about another axis:
    // the operator is Q_T A Q_Tᵀ exactly, and the preconditioner turned by R_now R_buildᵀ = T
    // inverts it (up to the content above degree p): at most three iterations. Turned the
    // other way round (R_buildᵀ R_now = Aᵀ T A), or not at all, it would not be.
    let p = 8;
    let a = rotation([1.0, 0.0, 0.0], 50f64.to_radians());
    let t = rotation([0.0, 0.0, 1.0], 35f64.to_radians());
    let mut built = shapes::rbc(p).unwrap();
    built.rotate(a).unwrap();
    let mut again = built.clone();
    again.rotate(t).unwrap();
    let frozen = VesicleParams {
        correct_drift: false,
        reparametrize: None,
        ..params(p)
    };
    let mut st = VesicleStepper::new(p, frozen).unwrap();
    st.set_preconditioning(Preconditioning::CELL);
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let mut c1 = built.coefs().to_vec();
    let first = st.step(&mut c1, &shear).unwrap();
    assert!(first.preconditioner_built && first.gmres.iterations <= 2);
    let mut c2 = again.coefs().to_vec();
    let second = st.step(&mut c2, &shear).unwrap();
    assert!(!second.preconditioner_built, "not rebuilt: it was fresh");
    assert!(
        second.gmres.iterations <= 3,
        "turned cell: {} iterations",
        second.gmres.iterations
    );
    // Control: the sphere's preconditioner needs many more for this cell.
    let mut sp = VesicleStepper::new(p, frozen).unwrap();
    let mut c3 = again.coefs().to_vec();
    let sphere = sp.step(&mut c3, &shear).unwrap().gmres.iterations;
    assert!(sphere >= 3 * second.gmres.iterations, "sphere {sphere}");
}

/// One cell run `before` steps, its state (with the own preconditioner's record) moved into a
/// fresh suspension, and both run `after` more: the same states, bit for bit, records included
/// (rebuilt after a step of more than 4 iterations).
fn moved_cell_continues_bit_for_bit(surface: &[f64], p: usize, before: usize, after: usize) {
    let setup = CellSetup {
        coefs: surface.to_vec(),
        params: params(p),
        skalak: None,
    };
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let fresh = || {
        let mut s = Suspension::new(p, vec![setup.clone()], CouplingParams::default()).unwrap();
        s.set_preconditioning(Preconditioning::Cell { rebuild_after: 4 });
        s
    };
    let mut a = fresh();
    for _ in 0..before {
        a.step(&shear).unwrap();
    }
    let snap = a.snapshot();
    assert!(
        a.cell_state(0).preconditioner.is_some(),
        "a record to carry"
    );
    let mut b = fresh();
    b.restore(&snap).unwrap();
    for k in 0..after {
        a.step(&shear).unwrap();
        b.step(&shear).unwrap();
        let (sa, sb) = (a.cell_state(0), b.cell_state(0));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&sa.coefs), bits(&sb.coefs), "step {k} after the move");
        assert_eq!(sa.preconditioner, sb.preconditioner, "record at step {k}");
        assert_eq!(sa.iterations, sb.iterations);
    }
}

#[test]
fn a_moved_or_resumed_cell_rebuilds_the_same_preconditioner() {
    let p = 6;
    // Built: an RBC's own operator.
    moved_cell_continues_bit_for_bit(shapes::rbc(p).unwrap().coefs(), p, 4, 6);
    // Singular: a sphere's own operator is refused; the sphere's preconditioner then takes 5–8
    // iterations, more than rebuild_after (4) but fewer than the retry limit (12): a moved cell
    // must know that its record was singular, or it would build afresh where the original
    // does not.
    moved_cell_continues_bit_for_bit(shapes::sphere(p, 1.0).unwrap().coefs(), p, 4, 6);
}
