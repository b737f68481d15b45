//! The `[dpd]` scene section of `mobo dpd`.
//!
//! ```toml
//! [dpd]
//! box = [10.0, 10.0, 20.0]   # periodic box (a number: a cube)
//! density = 3.0              # number density n
//! a = 25.0                   # conservative amplitude
//! gamma = 4.5                # dissipative coefficient γ
//! kbt = 1.0                  # thermal energy (σ² = 2γk_BT)
//! rc = 1.0                   # cut-off radius (default 1)
//! power = 1.0                # kernel exponent k: w_D = w^(2k) (default 1)
//! dt = 0.01
//! steps = 10000              # or t_end = 100.0
//! seed = 1
//! mass = 1.0                 # particle mass (default 1)
//! flow = "periodic_poiseuille"   # "none" (default) | "periodic_poiseuille"
//! force = 0.1                # body force per particle: +x for z < L_z/2, −x above
//! equilibrate = 1000         # steps before the profile is averaged (default: a fifth)
//! sample_every = 10          # steps between profile samples (default 10)
//! blocks = 10                # blocks for the standard error (default 10)
//! bins = 20                  # profile bins along z (default 20, rounded up to even)
//! save_every = 1000          # steps between observables rows and checkpoints (default 1000)
//! ```
//!
//! Walls (frozen particles and bounce-back, [`crate::dpd::walls`]):
//!
//! ```toml
//! walls = { kind = "planes", gap = 10.0 }    # a channel along x, y; box z ≥ gap + 2 rc
//! walls = { kind = "cylinder", radius = 5.0 }  # a pipe along x; box y, z ≥ 2 (radius + rc)
//! wall_warmup = 300          # steps the periodic fluid is equilibrated before freezing walls
//! flow = "poiseuille"        # with walls: the body force `force` along x everywhere
//! ```
//!
//! Membranes (cells in the DPD fluid) are not built yet.

use std::path::Path;

use serde::Deserialize;

use super::{parse_toml, read_scene_file, SceneError};
use crate::dpd::pair_force::PairParams;
use crate::dpd::system::{BodyForce, DpdParams};
use crate::dpd::walls::Wall;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    dpd: DpdSection,
}

/// A number (a cube) or three side lengths.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum BoxLen {
    Cube(f64),
    Sides([f64; 3]),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DpdSection {
    #[serde(rename = "box")]
    box_len: BoxLen,
    density: f64,
    a: f64,
    gamma: f64,
    kbt: f64,
    #[serde(default = "one")]
    rc: f64,
    #[serde(default = "one")]
    power: f64,
    dt: f64,
    steps: Option<u64>,
    t_end: Option<f64>,
    #[serde(default)]
    seed: u64,
    #[serde(default = "one")]
    mass: f64,
    #[serde(default = "default_flow")]
    flow: String,
    force: Option<f64>,
    equilibrate: Option<u64>,
    #[serde(default = "ten")]
    sample_every: u64,
    #[serde(default = "ten")]
    blocks: u64,
    #[serde(default = "twenty")]
    bins: usize,
    #[serde(default = "thousand")]
    save_every: u64,
    walls: Option<WallsSection>,
    #[serde(default = "three_hundred")]
    wall_warmup: u64,
}

/// `walls = { kind = "planes", gap = 10.0 }` or `{ kind = "cylinder", radius = 5.0 }`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct WallsSection {
    kind: String,
    gap: Option<f64>,
    radius: Option<f64>,
}

fn three_hundred() -> u64 {
    300
}

fn one() -> f64 {
    1.0
}
fn ten() -> u64 {
    10
}
fn twenty() -> usize {
    20
}
fn thousand() -> u64 {
    1000
}
fn default_flow() -> String {
    "none".into()
}

/// A validated DPD scene.
#[derive(Clone, Debug)]
pub struct DpdScene {
    /// Fluid parameters.
    pub params: DpdParams,
    /// Number density.
    pub density: f64,
    /// Body force.
    pub body: BodyForce,
    /// Steps to run.
    pub steps: u64,
    /// Steps discarded before profile averaging.
    pub equilibrate: u64,
    /// Steps between profile samples.
    pub sample_every: u64,
    /// Blocks of the block average.
    pub blocks: u64,
    /// Profile bins along `z`.
    pub bins: usize,
    /// Steps between observables rows and checkpoints.
    pub save_every: u64,
    /// Walls, if any.
    pub wall: Option<Wall>,
    /// Steps the periodic fluid is equilibrated before the wall particles are frozen.
    pub wall_warmup: u64,
}

impl DpdScene {
    /// Samples per block of the viscosity average (0: too short a run to average).
    pub fn block_samples(&self) -> u64 {
        let samples = self.steps.saturating_sub(self.equilibrate) / self.sample_every;
        samples / self.blocks
    }
}

/// Read and validate a DPD scene file.
pub fn load(file: &Path) -> Result<DpdScene, SceneError> {
    let text = read_scene_file(file)?;
    parse(file, &text)
}

/// Validate scene text (`file` is used in messages).
pub fn parse(file: &Path, text: &str) -> Result<DpdScene, SceneError> {
    let f: File = parse_toml(file, text)?;
    let d = f.dpd;
    let bad = |key: &str, why: String| SceneError::new(file, format!("[dpd] {key}: {why}"));
    let place = |key: &str| key_place(text, key);
    let located = |key: &str, why: String| {
        let mut e = bad(key, why);
        e.place = place(key);
        e
    };
    let box_len = match d.box_len {
        BoxLen::Cube(l) => [l; 3],
        BoxLen::Sides(s) => s,
    };
    for (key, v) in [
        ("density", d.density),
        ("dt", d.dt),
        ("rc", d.rc),
        ("mass", d.mass),
        ("power", d.power),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(located(key, format!("must be a positive number, got {v}")));
        }
    }
    for (key, v) in [("a", d.a), ("gamma", d.gamma), ("kbt", d.kbt)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(located(key, format!("must be a number ≥ 0, got {v}")));
        }
    }
    for (k, l) in box_len.iter().enumerate() {
        if !(l.is_finite() && *l >= 3.0 * d.rc) {
            return Err(located(
                "box",
                format!(
                    "side {} is {l}: each side must be at least 3 rc = {} (the cell list needs 3 cells per axis)",
                    ["x", "y", "z"][k],
                    3.0 * d.rc
                ),
            ));
        }
    }
    let wall = match &d.walls {
        None => None,
        Some(w) => {
            let need = |v: Option<f64>, key: &str| {
                v.ok_or_else(|| located("walls", format!("kind = \"{}\" needs {key}", w.kind)))
            };
            let built = match w.kind.as_str() {
                "planes" => {
                    if w.radius.is_some() {
                        return Err(located("walls", "planes take gap, not radius".into()));
                    }
                    Wall::channel(need(w.gap, "gap")?, box_len[2], d.rc)
                }
                "cylinder" => {
                    if w.gap.is_some() {
                        return Err(located("walls", "a cylinder takes radius, not gap".into()));
                    }
                    Wall::pipe(need(w.radius, "radius")?, box_len[1], box_len[2], d.rc)
                }
                other => {
                    return Err(located(
                        "walls",
                        format!("unknown kind \"{other}\" (expected \"planes\" or \"cylinder\")"),
                    ))
                }
            };
            Some(built.map_err(|e| located("walls", e.to_string()))?)
        }
    };
    let n = d.density * box_len.iter().product::<f64>();
    if !(2.0..4.0e9).contains(&n) {
        return Err(located(
            "density",
            format!("density × box volume = {n:.3e} particles; need between 2 and 4·10⁹"),
        ));
    }
    let steps = match (d.steps, d.t_end) {
        (Some(_), Some(_)) => {
            return Err(located(
                "t_end",
                "give either steps or t_end, not both".into(),
            ))
        }
        (Some(s), None) => s,
        (None, Some(t)) if t.is_finite() && t > 0.0 => (t / d.dt).round() as u64,
        (None, Some(t)) => return Err(located("t_end", format!("must be positive, got {t}"))),
        (None, None) => return Err(bad("steps", "give steps or t_end".into())),
    };
    if steps == 0 {
        return Err(located("steps", "must be at least 1".into()));
    }
    for (key, v) in [
        ("sample_every", d.sample_every),
        ("blocks", d.blocks),
        ("save_every", d.save_every),
    ] {
        if v == 0 {
            return Err(located(key, "must be at least 1".into()));
        }
    }
    if d.bins < 2 {
        return Err(located(
            "bins",
            format!("must be at least 2, got {}", d.bins),
        ));
    }
    let body = match d.flow.as_str() {
        "none" => {
            if d.force.is_some() {
                return Err(located(
                    "force",
                    "given but flow = \"none\" (set flow = \"periodic_poiseuille\")".into(),
                ));
            }
            BodyForce::None
        }
        "periodic_poiseuille" if wall.is_some() => {
            return Err(located(
                "flow",
                "periodic_poiseuille needs a periodic box; with walls use flow = \"poiseuille\"".into(),
            ))
        }
        "poiseuille" if wall.is_none() => {
            return Err(located(
                "flow",
                "poiseuille is driven between walls; give walls, or use \"periodic_poiseuille\"".into(),
            ))
        }
        "periodic_poiseuille" | "poiseuille" if d.bins < 12 => {
            return Err(located(
                "bins",
                format!(
                    "{} bins are too few for the viscosity fit (it uses the middle 70 % of each half-channel); give at least 12",
                    d.bins
                ),
            ))
        }
        "periodic_poiseuille" => match d.force {
            Some(g) if g.is_finite() && g != 0.0 => BodyForce::ReversePoiseuille { force: g },
            Some(g) => {
                return Err(located(
                    "force",
                    format!("must be a non-zero number, got {g}"),
                ))
            }
            None => {
                return Err(bad(
                    "force",
                    "required for flow = \"periodic_poiseuille\"".into(),
                ))
            }
        },
        "poiseuille" => match d.force {
            Some(g) if g.is_finite() && g != 0.0 => BodyForce::Constant([g, 0.0, 0.0]),
            Some(g) => return Err(located("force", format!("must be a non-zero number, got {g}"))),
            None => return Err(bad("force", "required for flow = \"poiseuille\"".into())),
        },
        other => {
            return Err(located(
                "flow",
                format!(
                    "unknown flow \"{other}\" (expected \"none\", \"periodic_poiseuille\" or \"poiseuille\")"
                ),
            ))
        }
    };
    let equilibrate = d.equilibrate.unwrap_or(steps / 5);
    if equilibrate >= steps {
        return Err(located(
            "equilibrate",
            format!("{equilibrate} steps leave none of the {steps} to average"),
        ));
    }
    let params = DpdParams {
        box_len,
        pair: PairParams {
            a: d.a,
            gamma: d.gamma,
            kbt: d.kbt,
            rc: d.rc,
            power: d.power,
        },
        dt: d.dt,
        mass: d.mass,
        seed: d.seed,
    };
    params
        .validate()
        .map_err(|e| SceneError::new(file, format!("[dpd]: {e}")))?;
    Ok(DpdScene {
        params,
        density: d.density,
        body,
        steps,
        equilibrate,
        sample_every: d.sample_every,
        blocks: d.blocks,
        bins: d.bins,
        save_every: d.save_every,
        wall,
        wall_warmup: d.wall_warmup,
    })
}

/// Line and column of `key = …` in the text (the first line that assigns it).
fn key_place(text: &str, key: &str) -> Option<(usize, usize)> {
    text.lines().enumerate().find_map(|(i, line)| {
        let t = line.trim_start();
        let rest = t.strip_prefix(key)?;
        rest.trim_start()
            .starts_with('=')
            .then(|| (i + 1, line.len() - t.len() + 1))
    })
}
