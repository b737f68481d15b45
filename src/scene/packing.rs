//! `placement = "packed"`: `count` cells at a volume fraction `φ`, every pair of surfaces at
//! least `min_gap` apart, in a cube or in the fluid the scene's walls bound.
//!
//! The protocol grows shrunk cells to full size with contacts active, as Lubachevsky &
//! Stillinger (J. Stat. Phys. 60, 1990) grow hard particles, with the contact projection of
//! [`crate::timestep::contact`] in place of event-driven collisions:
//!
//! 1. The region. Without a container wall: the cube of side `L = (N V / φ)^{1/3}` with
//!    `V = 4πr³/3` the volume of one cell of equivalent radius `r`, centred on the entry's
//!    `center`; volume fraction is `N V / L³`. In a scene with a container (`[[walls]]
//!    kind = "container"`, e.g. a tube): the fluid inside it and outside its bodies, whose
//!    volume `V_f` (the walls' enclosed volumes) fixes the number of cells,
//!    `N = round(φ V_f / V)` ([`cells_in_walls`]); the volume fraction is then `N V / V_f`.
//! 2. Every cell gets a uniformly random orientation (a uniform unit quaternion) and a uniformly
//!    random centre in the region, at half its size (`s = 1/2`): in the cube's inner 90 %, or
//!    in the walls' fluid at least half the cell's bounding radius plus `min_gap` from every
//!    wall (rejection sampling in the container's bounding box, by the true distance).
//! 3. The projection moves (translations and small rotations) the cells until every surface gap
//!    (true distance: Newton's closest points, [`crate::vesicle::surface_distance`]) and every
//!    gap to the cube's faces, or to every wall (a fixed surface of the projection), is at least
//!    `min_gap`.
//! 4. The size grows by a factor `1 + g` (`g = 4 %` at first) and step 3 repeats; a growth the
//!    projection cannot resolve in 40 rounds (or 10 without progress) is undone and retried with `g / 2`, a resolved one
//!    lets `g` grow back by 1.5 (up to 4 %). The protocol ends at full size, or fails (jammed)
//!    when `g` falls below `10⁻⁴` or after 30 failed growths.
//!
//! **A recycled tube** (`[flow] recycle = true`, [`TubeWindow`]): the cells are packed in the
//! tube's straight section, the window `x_in ≤ x < x_out` of length `P` they are recycled
//! through, as a periodic suspension. The volume fraction is of the window's cylinder,
//! `N = round(φ π R² P / V)` (the tube hematocrit); centres start in the window; the
//! projection keeps every cell `min_gap` from the others' images shifted by `(P, 0, 0)` as well
//! ([`ContactParams::period`]), and after every growth a centre that left the window is wrapped
//! back by `±P`. So a cell that leaves through the outlet finds its landing place clear of the
//! cells near the inlet, as it was at the start, and the tube's rounded ends start empty.
//!
//! Deterministic for a given `seed`. The surfaces are those of the scene's order `p`.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::cell_scene::{CellSpec, TubeWindow, WallShape, WallSpec};
pub use super::packing_report::PackingReport;
use crate::linalg3::{dot3, matmul3};
use crate::timestep::contact::{ContactParams, ContactSolver, FixedSurface, Wall};
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::surface_distance::DistanceScratch;
use crate::wall::WallKind;

/// Random centres tried per cell before the walls' fluid is declared too small to start in.
const CENTRE_TRIES: usize = 10_000;

/// Relative growth of the first attempts.
const GROWTH: f64 = 0.04;

/// Growth below which the packing is jammed.
const MIN_GROWTH: f64 = 1e-4;

/// Failed growths after which the packing is jammed.
const MAX_FAILURES: usize = 30;

/// Size at which the cells start.
const START: f64 = 0.5;

/// Projections repeated at the same size after wrapping centres back into a recycled tube's
/// window (beyond them a centre may end just outside it).
const MAX_WRAPS: usize = 200;

/// What was asked, and what a placement achieved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PackingRequest {
    /// Cells.
    pub count: usize,
    /// Volume fraction `φ`.
    pub volume_fraction: f64,
    /// Smallest surface gap.
    pub min_gap: f64,
    /// Seed of the random positions and orientations.
    pub seed: u64,
    /// SH order of the surfaces.
    pub order: usize,
}

/// The side of the packing cube.
pub fn cube_side(base: &CellSpec, req: &PackingRequest) -> f64 {
    let v = 4.0 / 3.0 * std::f64::consts::PI * base.radius.powi(3);
    (req.count as f64 * v / req.volume_fraction).cbrt()
}

/// The volume of the fluid the scene's walls bound: the container's enclosed volume less its
/// bodies' (`None` without a container).
pub fn fluid_volume(walls: &[WallSpec]) -> Result<Option<f64>, String> {
    if !walls.iter().any(|w| w.kind == WallKind::Container) {
        return Ok(None);
    }
    let mut volume = 0.0;
    for (k, w) in walls.iter().enumerate() {
        let s = w.surface().map_err(|e| format!("wall {k}: {e}"))?;
        let v = SurfaceCalculus::new(w.order)
            .and_then(|mut c| c.geometry(s.coefs()))
            .map_err(|e| format!("wall {k}: {e}"))?
            .volume();
        volume += match w.kind {
            WallKind::Container => v,
            WallKind::Body => -v,
        };
    }
    Ok(Some(volume))
}

/// The number of cells like `base` at volume fraction `phi` of the fluid of volume
/// `fluid_volume` ([`fluid_volume`]), `N = round(φ V_f / V)` (at least one), and the volume
/// fraction `N V / V_f` they fill.
pub fn cells_in_walls(base: &CellSpec, phi: f64, fluid_volume: f64) -> (usize, f64) {
    let v = 4.0 / 3.0 * std::f64::consts::PI * base.radius.powi(3);
    let n = ((phi * fluid_volume / v).round() as usize).max(1);
    (n, n as f64 * v / fluid_volume)
}

/// The volume of a recycled tube's window `π R² P` (`None` without a tube container).
pub fn window_volume(walls: &[WallSpec], window: &TubeWindow) -> Option<f64> {
    walls.iter().find_map(|w| match (w.kind, &w.shape) {
        (WallKind::Container, &WallShape::Tube { radius, .. }) => {
            Some(std::f64::consts::PI * radius * radius * (window.outlet - window.inlet))
        }
        _ => None,
    })
}

/// The walls as the projection's fixed surfaces, which also measure the centre sampling's
/// clearance, and the box the centres are drawn from.
struct PackingWalls {
    fixed: Vec<FixedSurface>,
    /// The box's centre and half extents: the container's bounding box, or a recycled tube's
    /// window.
    bounds: ([f64; 3], [f64; 3]),
}

impl PackingWalls {
    fn new(walls: &[WallSpec], window: Option<&TubeWindow>) -> Result<Option<Self>, String> {
        let Some(container) = walls.iter().find(|w| w.kind == WallKind::Container) else {
            return Ok(None);
        };
        let mut centre = container.center;
        let mut half = match container.shape {
            WallShape::Sphere { radius } => [radius; 3],
            WallShape::Ellipsoid { axes } => axes,
            WallShape::Tube { radius, length } => [length / 2.0, radius, radius],
            WallShape::Channel {
                length,
                width,
                height,
            } => [length / 2.0, width / 2.0, height / 2.0],
            WallShape::Grid { .. } => {
                // The bounding box of the surface's grid points.
                let s = container
                    .surface()
                    .map_err(|e| format!("the container: {e}"))?;
                let sht = crate::sph_harmonics::ShTransform::new(container.order)
                    .map_err(|e| format!("the container: {e}"))?;
                let x = s
                    .grid_positions(&sht)
                    .map_err(|e| format!("the container: {e}"))?;
                let n = x.len() / 3;
                let mut half = [0.0; 3];
                for a in 0..3 {
                    let v = &x[a * n..(a + 1) * n];
                    let (lo, hi) = v
                        .iter()
                        .fold((f64::MAX, f64::MIN), |(l, h), &y| (l.min(y), h.max(y)));
                    centre[a] = 0.5 * (lo + hi);
                    half[a] = 0.5 * (hi - lo);
                }
                half
            }
        };
        if let Some(w) = window {
            centre[0] = 0.5 * (w.inlet + w.outlet);
            half[0] = 0.5 * (w.outlet - w.inlet);
        }
        let fixed = walls
            .iter()
            .enumerate()
            .map(|(k, w)| {
                let s = w.surface().map_err(|e| format!("wall {k}: {e}"))?;
                FixedSurface::new(w.order, s.coefs(), w.kind == WallKind::Container)
                    .map_err(|e| format!("wall {k}: {e}"))
            })
            .collect::<Result<Vec<_>, String>>()?;
        Ok(Some(PackingWalls {
            fixed,
            bounds: (centre, half),
        }))
    }

    /// `n` random centres at least `margin` inside the fluid.
    fn centres(&self, rng: &mut StdRng, n: usize, margin: f64) -> Result<Vec<[f64; 3]>, String> {
        let (c, h) = self.bounds;
        let mut scratch: Vec<DistanceScratch> = self
            .fixed
            .iter()
            .map(|f| DistanceScratch::new(f.order()))
            .collect();
        let mut out = Vec::with_capacity(n);
        let mut tries = 0;
        while out.len() < n {
            let x: [f64; 3] =
                std::array::from_fn(|d| c[d] + h[d] * (2.0 * rng.random::<f64>() - 1.0));
            // The smallest distance of `x` from the walls, positive in the fluid.
            let clearance = self
                .fixed
                .iter()
                .zip(&mut scratch)
                .map(|(f, s)| f.clearance(s, x))
                .fold(f64::INFINITY, f64::min);
            if clearance >= margin {
                out.push(x);
            } else {
                tries += 1;
                if tries > CENTRE_TRIES * n {
                    return Err(format!(
                        "no point of the walls' fluid is {margin:.3} from every wall, the room a \
                         cell needs at half its size: the walls leave no room for these cells"
                    ));
                }
            }
        }
        Ok(out)
    }
}

/// `req.count` copies of `base` packed in the cube of [`cube_side`] about `base.center`, or,
/// in a scene with a container wall, in the fluid of `walls` (see the module docs; the count
/// then comes from [`cells_in_walls`]), or periodically in a recycled tube's `window`; an error
/// says how far the growth came.
pub fn pack(
    base: &CellSpec,
    req: &PackingRequest,
    walls: &[WallSpec],
    window: Option<&TubeWindow>,
) -> Result<(Vec<CellSpec>, PackingReport), String> {
    let started = std::time::Instant::now();
    let n = req.count;
    let side = cube_side(base, req);
    let c = base.center;
    let mut rng = StdRng::seed_from_u64(req.seed);
    let region = PackingWalls::new(walls, window)?;
    let window = window.filter(|_| region.is_some());
    let mut centres: Vec<[f64; 3]> = match &region {
        None => (0..n)
            .map(|_| std::array::from_fn(|d| c[d] + side * (rng.random::<f64>() - 0.5) * 0.9))
            .collect(),
        Some(r) => r.centres(&mut rng, n, START * base.bounding_radius + req.min_gap)?,
    };
    let mut rotations: Vec<[[f64; 3]; 3]> = (0..n).map(|_| random_rotation(&mut rng)).collect();
    // The shape at the origin, full size, in its own frame.
    let mut unit = base.clone();
    unit.center = [0.0; 3];
    unit.rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let shape = unit.surface(req.order).map_err(|e| e.to_string())?;
    let planes: Vec<Wall> = match region {
        Some(_) => vec![],
        None => (0..3)
            .flat_map(|d| {
                let mut e = [0.0; 3];
                e[d] = 1.0;
                let lo = Wall {
                    normal: e,
                    offset: c[d] - side / 2.0,
                };
                let hi = Wall {
                    normal: e.map(|v| -v),
                    offset: -(c[d] + side / 2.0),
                };
                [lo, hi]
            })
            .collect(),
    };
    let fixed: &[FixedSurface] = region.as_ref().map_or(&[], |r| &r.fixed);
    let mut params = ContactParams::new(req.min_gap);
    params.rotations = true;
    params.spread = true;
    params.max_rounds = 40;
    params.stall_rounds = 10;
    params.period = window.map(|w| [w.outlet - w.inlet, 0.0, 0.0]);
    let solver = ContactSolver::new(req.order, params).map_err(|e| e.to_string())?;
    let surfaces = |size: f64, centres: &[[f64; 3]], rotations: &[[[f64; 3]; 3]]| {
        (0..n)
            .map(|i| {
                let mut s = shape.clone();
                for v in s.coefs_mut() {
                    *v *= size;
                }
                s.rotate(rotations[i]).map_err(|e| e.to_string())?;
                s.translate(centres[i]);
                Ok(s.coefs().to_vec())
            })
            .collect::<Result<Vec<Vec<f64>>, String>>()
    };
    let (mut size, mut growth) = (START, GROWTH);
    let mut smallest_gap: f64;
    let (mut trial, mut failures, mut wraps) = (size, 0, 0);
    loop {
        let coefs = surfaces(trial, &centres, &rotations)?;
        let refs: Vec<&[f64]> = coefs.iter().map(|v| v.as_slice()).collect();
        match solver.resolve_with(&refs, &planes, fixed) {
            Ok(out) => {
                for (i, m) in out.moves.iter().enumerate() {
                    // x ↦ m.c + R (x − m.c) + t keeps the shape's frame: the rotation becomes
                    // R R_i and the centre R (c_i − m.c) + m.c + t.
                    let d = [
                        centres[i][0] - m.centre[0],
                        centres[i][1] - m.centre[1],
                        centres[i][2] - m.centre[2],
                    ];
                    centres[i] = std::array::from_fn(|k| {
                        dot3(m.rotation[k], d) + m.centre[k] + m.translation[k]
                    });
                    rotations[i] = matmul3(m.rotation, rotations[i]);
                }
                size = trial;
                smallest_gap = out.gap_after;
                // In a recycled tube's window, a centre that left it is wrapped back: the
                // same periodic suspension, and a projection at the same size checks the
                // walls at its new place.
                let wrapped = window.map_or(0, |w| wrap(&mut centres, w));
                if wrapped > 0 && wraps < MAX_WRAPS {
                    wraps += 1;
                    trial = size;
                    continue;
                }
                if size >= 1.0 {
                    break;
                }
                growth = (1.5 * growth).min(GROWTH);
            }
            Err(_) => {
                growth /= 2.0;
                failures += 1;
                if growth < MIN_GROWTH || failures > MAX_FAILURES {
                    return Err(format!(
                        "could not pack {n} cells at a volume fraction of {:.1} % {} with gaps \
                         of at least {}: jammed at {:.1} % of the cells' size (a volume fraction \
                         of {:.1} %); lower volume_fraction or min_gap",
                        100.0 * req.volume_fraction,
                        match (fixed.is_empty(), window) {
                            (true, _) => "in a cube",
                            (false, None) => "of the walls' fluid",
                            (false, Some(_)) => "of the recycled tube's window",
                        },
                        req.min_gap,
                        100.0 * size,
                        100.0 * req.volume_fraction * size.powi(3)
                    ));
                }
            }
        }
        trial = (size * (1.0 + growth)).min(1.0);
    }
    let cells = (0..n)
        .map(|i| CellSpec {
            center: centres[i],
            rotation: rotations[i],
            ..base.clone()
        })
        .collect();
    let report = PackingReport {
        entry: 0,
        cells: n,
        volume_fraction: req.volume_fraction,
        region: match (fixed.is_empty(), window) {
            (true, _) => "cube",
            (false, None) => "walls",
            (false, Some(_)) => "tube window",
        },
        smallest_gap: smallest_gap.is_finite().then_some(smallest_gap),
        seconds: started.elapsed().as_secs_f64(),
    };
    Ok((cells, report))
}

/// Wrap the centres that left the window back into it by `±P`; how many were wrapped.
fn wrap(centres: &mut [[f64; 3]], w: &TubeWindow) -> usize {
    let period = w.outlet - w.inlet;
    let mut n = 0;
    for c in centres {
        if c[0] >= w.outlet {
            c[0] -= period;
            n += 1;
        } else if c[0] < w.inlet {
            c[0] += period;
            n += 1;
        }
    }
    n
}

/// A uniformly random rotation (Shoemake's uniform unit quaternion).
fn random_rotation(rng: &mut StdRng) -> [[f64; 3]; 3] {
    let (u1, u2, u3): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
    let tau = 2.0 * std::f64::consts::PI;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let (w, x, y, z) = (
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
        b * (tau * u3).cos(),
    );
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}
