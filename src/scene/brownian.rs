//! The `[brownian]` scene section.
//!
//! ```toml
//! [brownian]
//! radius = 1.0            # bead radius a
//! kT = 1.0                # thermal energy
//! viscosity = 0.0530516   # solvent viscosity η (D0 = kT / 6πηa)
//! dt = 1e-3
//! steps = 10000
//! seed = 1
//! noise = "tea-hi"        # "tea-hi" | "exact" | "lanczos" | "free-draining"
//! lanczos_tol = 1e-6      # for "lanczos"
//! save_every = 100        # steps between saved frames
//! gpu = "auto"            # TEA-HI pass on a GPU: "auto" | true | false (feature gpu)
//!
//! [brownian.system]
//! kind = "chain"          # "dimer" | "chain" | "positions" | "random"
//! beads = 10              # chain, random
//! bond_length = 2.0       # dimer, chain (dimer: the separation d)
//! bond_stiffness = 50.0   # a_h in kT / length²
//! repulsion = 50.0        # overlap repulsion a_r (0 = none)
//! positions = [[0, 0, 0], [2, 0, 0]]   # positions
//! box = 20.0              # random: cube side
//! external_force = [0, 0, 0]
//!
//! [brownian.sce]          # optional sub-cellular-element potential
//! u0 = 1.0
//! rho = 2.0
//! r_eq = 2.0
//! cutoff = 5.0
//! ```

use std::path::Path;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Deserialize;

use super::{parse_toml, read_scene_file, GpuFlag, SceneError};
use crate::brownian::{BrownianParams, ForceField, NoiseModel, SubcellularElement};
use crate::gpu::GpuChoice;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    brownian: BrownianSection,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BrownianSection {
    radius: f64,
    #[serde(rename = "kT")]
    kt: f64,
    viscosity: f64,
    dt: f64,
    steps: u64,
    #[serde(default)]
    seed: u64,
    #[serde(default = "default_noise")]
    noise: String,
    #[serde(default = "default_lanczos_tol")]
    lanczos_tol: f64,
    #[serde(default = "default_save_every")]
    save_every: u64,
    system: SystemSection,
    sce: Option<SubcellularElement>,
    /// The TEA-HI pass on a GPU: "auto" (default), true or false.
    gpu: Option<GpuFlag>,
}

fn default_noise() -> String {
    "tea-hi".into()
}
fn default_lanczos_tol() -> f64 {
    1e-6
}
fn default_save_every() -> u64 {
    100
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SystemSection {
    kind: String,
    beads: Option<usize>,
    bond_length: Option<f64>,
    #[serde(default)]
    bond_stiffness: f64,
    #[serde(default)]
    repulsion: f64,
    positions: Option<Vec<[f64; 3]>>,
    #[serde(rename = "box")]
    box_len: Option<f64>,
    #[serde(default)]
    external_force: [f64; 3],
}

/// A validated Brownian scene.
#[derive(Clone, Debug)]
pub struct BrownianScene {
    /// Integrator parameters.
    pub params: BrownianParams,
    /// Initial positions.
    pub positions: Vec<[f64; 3]>,
    /// Forces.
    pub forces: ForceField,
    /// Number of steps.
    pub steps: u64,
    /// Steps between saved frames.
    pub save_every: u64,
    /// The system kind, as written.
    pub kind: String,
    /// The TEA-HI pass on a GPU (`[brownian] gpu`, default `"auto"`).
    pub gpu: GpuChoice,
}

/// Read and validate a Brownian scene file.
pub fn load(file: &Path) -> Result<BrownianScene, SceneError> {
    let text = read_scene_file(file)?;
    parse(file, &text)
}

/// Validate scene text (`file` is used in messages).
pub fn parse(file: &Path, text: &str) -> Result<BrownianScene, SceneError> {
    let f: File = parse_toml(file, text)?;
    let b = f.brownian;
    let bad = |key: &str, why: &str| SceneError::new(file, format!("[brownian] {key}: {why}"));
    for (key, v) in [
        ("radius", b.radius),
        ("kT", b.kt),
        ("viscosity", b.viscosity),
        ("dt", b.dt),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(bad(key, &format!("must be a positive number, got {v}")));
        }
    }
    if b.save_every == 0 {
        return Err(bad("save_every", "must be at least 1"));
    }
    let gpu = match &b.gpu {
        None => GpuChoice::Auto,
        Some(flag) => flag.choice().map_err(|why| bad("gpu", &why))?,
    };
    let noise = match b.noise.as_str() {
        "tea-hi" => NoiseModel::TeaHi,
        "exact" => NoiseModel::Cholesky,
        "lanczos" => {
            if !(b.lanczos_tol > 0.0 && b.lanczos_tol < 1.0) {
                return Err(bad("lanczos_tol", "must be in (0, 1)"));
            }
            NoiseModel::Lanczos {
                tol: b.lanczos_tol,
                max_iter: 200,
            }
        }
        "free-draining" => NoiseModel::FreeDraining,
        other => {
            return Err(bad(
                "noise",
                &format!(
                    "unknown model \"{other}\" (expected tea-hi, exact, lanczos or free-draining)"
                ),
            ))
        }
    };
    let s = b.system;
    let sbad =
        |key: &str, why: &str| SceneError::new(file, format!("[brownian.system] {key}: {why}"));
    if !(s.bond_stiffness >= 0.0 && s.repulsion >= 0.0) {
        return Err(sbad("bond_stiffness/repulsion", "must not be negative"));
    }
    let bond_length = |kind: &str| -> Result<f64, SceneError> {
        match s.bond_length {
            Some(l) if l.is_finite() && l > 0.0 => Ok(l),
            Some(l) => Err(sbad("bond_length", &format!("must be positive, got {l}"))),
            None => Err(sbad(
                "bond_length",
                &format!("required for kind = \"{kind}\""),
            )),
        }
    };
    let (positions, bonds) = match s.kind.as_str() {
        "dimer" => {
            let l = bond_length("dimer")?;
            (vec![[0.0; 3], [l, 0.0, 0.0]], vec![(0, 1)])
        }
        "chain" => {
            let l = bond_length("chain")?;
            let n = s
                .beads
                .ok_or_else(|| sbad("beads", "required for kind = \"chain\""))?;
            if n < 2 {
                return Err(sbad("beads", "a chain needs at least 2 beads"));
            }
            (
                (0..n).map(|i| [i as f64 * l, 0.0, 0.0]).collect(),
                (0..n - 1).map(|i| (i, i + 1)).collect(),
            )
        }
        "positions" => {
            let p = s
                .positions
                .ok_or_else(|| sbad("positions", "required for kind = \"positions\""))?;
            if p.is_empty() || p.iter().flatten().any(|v| !v.is_finite()) {
                return Err(sbad(
                    "positions",
                    "must be a non-empty list of finite [x, y, z]",
                ));
            }
            (p, Vec::new())
        }
        "random" => {
            let n = s
                .beads
                .ok_or_else(|| sbad("beads", "required for kind = \"random\""))?;
            let l = s
                .box_len
                .ok_or_else(|| sbad("box", "required for kind = \"random\""))?;
            if !(l.is_finite() && l > 0.0) || n == 0 {
                return Err(sbad(
                    "box/beads",
                    "need a positive box and at least one bead",
                ));
            }
            (random_packing(n, l, b.radius, b.seed).ok_or_else(|| {
                sbad("beads", &format!("cannot place {n} non-overlapping beads of radius {} in a box of side {l}", b.radius))
            })?, Vec::new())
        }
        other => {
            return Err(sbad(
                "kind",
                &format!("unknown kind \"{other}\" (expected dimer, chain, positions or random)"),
            ))
        }
    };
    if let Some(sce) = b.sce {
        if !(sce.u0 >= 0.0 && sce.rho > 0.0 && sce.r_eq > 0.0 && sce.cutoff > 0.0) {
            return Err(SceneError::new(
                file,
                "[brownian.sce]: u0 ≥ 0 and rho, r_eq, cutoff > 0 required",
            ));
        }
    }
    let forces = ForceField {
        bonds,
        bond_stiffness: s.bond_stiffness,
        bond_length: s.bond_length.unwrap_or(0.0),
        repulsion: s.repulsion,
        radius: b.radius,
        sce: b.sce,
        external: s.external_force,
    };
    Ok(BrownianScene {
        params: BrownianParams {
            radius: b.radius,
            kt: b.kt,
            viscosity: b.viscosity,
            dt: b.dt,
            noise,
            seed: b.seed,
        },
        positions,
        forces,
        steps: b.steps,
        save_every: b.save_every,
        kind: s.kind,
        gpu,
    })
}

/// Random non-overlapping placement by rejection (`None` if it fails).
fn random_packing(n: usize, box_len: f64, a: f64, seed: u64) -> Option<Vec<[f64; 3]>> {
    let mut rng = StdRng::seed_from_u64(seed ^ 0x5eed);
    let mut out: Vec<[f64; 3]> = Vec::with_capacity(n);
    let mut tries = 0usize;
    while out.len() < n {
        tries += 1;
        if tries > 1000 * n + 10_000 {
            return None;
        }
        let p = [
            rng.random_range(0.0..box_len),
            rng.random_range(0.0..box_len),
            rng.random_range(0.0..box_len),
        ];
        if out
            .iter()
            .all(|q| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>() >= 4.0 * a * a)
        {
            out.push(p);
        }
    }
    Some(out)
}
