//! A scene's cells as a [`Suspension`] ready to step: the setups, the coupling and the memory
//! plan `mobo run` uses, for one process or one rank's share.

use super::cell_step::step_error;
use super::error::CellRunError;
use crate::linalg3::{cross3, sub3};
use crate::scene::cells::{CellScene, Effect, Flow, Scheme};
use crate::scene::walls::WallShape;
use crate::timestep::cell_preconditioner;
use crate::timestep::cell_stepper::LOCAL_AREA_RATE;
use crate::timestep::contact::ContactParams;
use crate::timestep::coupling::CouplingParams;
use crate::timestep::plane_coupling::PlaneCoupling;
use crate::timestep::semi_implicit::{OperatorStorage, Preconditioning, TimeScheme, VesicleParams};
use crate::timestep::suspension::CellStepError;
use crate::timestep::suspension::{CellSetup, Recycling, Suspension};
use crate::timestep::wall_coupling::WallCoupling;
use crate::timestep::GmresParams;
use crate::timestep::TimestepError;
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::reparam::ReparamParams;
use crate::vesicle::skalak::SkalakParams;
use crate::wall::{RowShare, Wall, WallKind, WallParams};

/// The setup of every cell of `scene`, in scene order (the settings `mobo run` uses: drift
/// correction every step, the grids relaxed as `[numerics] grid` says, GMRES restart 200).
pub fn setups(scene: &CellScene) -> Result<Vec<CellSetup>, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let mut setups = Vec::with_capacity(scene.cells.len());
    for cell in &scene.cells {
        let coefs = cell.surface(p)?.coefs().to_vec();
        let params = VesicleParams {
            bending_modulus: cell.bending_modulus,
            viscosity: scene.viscosity,
            force: cell.force,
            dt: scene.numerics.dt,
            upsampled_order: q,
            gmres: GmresParams {
                tol: scene.numerics.gmres_tol,
                restart: 200,
                max_iters: 5000,
                ..Default::default()
            },
            correct_drift: true,
            // A membrane with shear elasticity is measured from material points: by default
            // its grid follows them (`scene::cells::GridMotion`).
            reparametrize: scene.numerics.grid.relaxes(cell).then(|| ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
            preconditioner: true,
            scheme: match scene.numerics.scheme {
                Scheme::Euler => TimeScheme::Euler,
                Scheme::Bdf2 => TimeScheme::Bdf2,
            },
            viscosity_ratio: cell.viscosity_ratio,
            inextensible: cell.inextensible,
            elastic_stepping: scene.numerics.elasticity,
        };
        let skalak = if cell.shear_modulus > 0.0 {
            // The stress-free reference: the initial shape, or a smaller one (`prestress`).
            let reference = if cell.prestress == 0.0 {
                coefs.clone()
            } else {
                cell.reference_surface(p)?.coefs().to_vec()
            };
            Some((
                SkalakParams {
                    shear_modulus: cell.shear_modulus,
                    dilation_ratio: cell.skalak_c,
                    law: cell.elastic_law,
                },
                reference,
            ))
        } else {
            None
        };
        setups.push(CellSetup {
            coefs,
            params,
            skalak,
        });
    }
    Ok(setups)
}

/// The coupling settings of `scene` (the contact repulsion's strength, when the scene leaves
/// it out, from the cells' bending, the flow and the forces).
pub(super) fn coupling_params(scene: &CellScene) -> CouplingParams {
    let rate = scene.flow.rate_scale();
    let auto_strength = scene
        .cells
        .iter()
        .map(|c| {
            let r = c.radius;
            let f = c.force.iter().map(|v| v * v).sum::<f64>().sqrt();
            (c.bending_modulus / r.powi(3))
                .max(scene.viscosity * rate)
                .max(f / (4.0 * std::f64::consts::PI * r * r))
        })
        .fold(0.0, f64::max)
        * 10.0;
    CouplingParams {
        viscosity: scene.viscosity,
        fmm_digits: scene.numerics.fmm_digits,
        repulsion_range: scene.numerics.repulsion_range,
        repulsion_strength: scene.numerics.repulsion_strength.unwrap_or(auto_strength),
        gpu: scene.numerics.gpu,
        ..Default::default()
    }
}

/// The local area relaxation's rate for `scene`
/// ([`crate::timestep::cell_stepper::CellStepper::set_local_area_rate`]):
/// [`LOCAL_AREA_RATE`] per unit of the scene's fastest time scale, the largest of the flow's
/// rate, `G/(μ R)` and `κ/(μ R³)` over the cells (one unit without any). Not a body force's:
/// a traction given through the library's force hooks must step as the same body force does
/// (`tests/simulation.rs`).
pub(super) fn local_area_rate(scene: &CellScene) -> f64 {
    let mu = scene.viscosity;
    let scale = scene
        .cells
        .iter()
        .map(|c| {
            (c.shear_modulus / (mu * c.radius)).max(c.bending_modulus / (mu * c.radius.powi(3)))
        })
        .fold(scene.flow.rate_scale(), f64::max);
    LOCAL_AREA_RATE * if scale > 0.0 { scale } else { 1.0 }
}

/// The cells of `scene` as a [`Suspension`] ready to step (the settings `mobo run` uses:
/// drift correction and reparametrisation every step, GMRES restart 200). Library users and
/// studies (`mobo report`) step it themselves.
pub fn build(scene: &CellScene) -> Result<Suspension, CellRunError> {
    let setups = setups(scene)?;
    let all = (0..setups.len()).collect::<Vec<_>>();
    build_part(scene, &setups, &all)
}

/// One rank's share of the cells of `scene`: the cells `ids` (global indices) of `setups`
/// (every cell's, from [`setups`]), with the walls' whole system.
pub fn build_part(
    scene: &CellScene,
    setups: &[CellSetup],
    ids: &[usize],
) -> Result<Suspension, CellRunError> {
    build_part_share(scene, setups, ids, RowShare::WHOLE)
}

/// [`build_part`] holding only the rows `walls` of the walls' system
/// ([`crate::wall::WallRows`]; its steps are then collective over those ranks).
pub fn build_part_share(
    scene: &CellScene,
    setups: &[CellSetup],
    ids: &[usize],
    walls_share: RowShare,
) -> Result<Suspension, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let contrast = scene.cells.iter().any(|c| c.viscosity_ratio != 1.0);
    let cells = ids.iter().map(|&i| (i, setups[i].clone())).collect();
    let mut susp = Suspension::new_part(
        p,
        q.max(p),
        cells,
        setups.len(),
        contrast,
        coupling_params(scene),
    )
    .map_err(|e| step_error(0, 0.0, e))?;
    // Chosen for all cells alike (the memory of the whole scene), so that the split between
    // ranks does not change how a cell is stepped.
    let (storage, preconditioning) = memory_plan(scene, setups.len(), contrast);
    susp.set_operator_storage(storage);
    susp.set_preconditioning(preconditioning);
    susp.set_coupling_mode(scene.numerics.coupling);
    susp.set_implicit_zone(scene.numerics.implicit_zone);
    susp.set_start_up_passes(scene.numerics.start_up_passes);
    susp.set_start_up_anderson_depth(scene.numerics.start_up_anderson_depth);
    susp.set_local_area_rate(local_area_rate(scene))
        .map_err(|e| step_error(0, 0.0, e))?;
    susp.set_contacts(p, scene.numerics.contact_distance.map(ContactParams::new))
        .map_err(|e| step_error(0, 0.0, e))?;
    if !scene.walls.is_empty() {
        susp.set_walls(Some(
            walls(scene, walls_share).map_err(|e| step_error(0, 0.0, e))?,
        ));
    }
    if let Some(w) = &scene.plane {
        let plane = crate::wall::PlaneWall::new(w.point, w.normal).map_err(|e| {
            step_error(
                0,
                0.0,
                CellStepError {
                    cell: None,
                    source: TimestepError::from(e),
                },
            )
        })?;
        let coupling = PlaneCoupling::new(plane, scene.viscosity)
            .map_err(|source| step_error(0, 0.0, CellStepError { cell: None, source }))?;
        susp.set_plane(Some(coupling));
    }
    // A recycled cell lands at least the contact distance from everything (0.05 cell radii
    // without contacts), the gap the projection keeps between the cells it lands among.
    susp.set_recycling(scene.recycle.map(|w| Recycling {
        outlet: w.outlet,
        period: w.outlet - w.inlet,
        clearance: scene.numerics.contact_distance.unwrap_or(0.05),
        axis: w.axis,
    }));
    if !scene.numerics.far_side_split {
        let off = FarSideParams {
            enabled: false,
            ..FarSideParams::default()
        };
        susp.set_far_side_params(off)
            .map_err(|e| step_error(0, 0.0, e))?;
    }
    Ok(susp)
}

/// The scene's rigid walls, assembled and factored ([`WallCoupling`]): the rows of `share`.
fn walls(scene: &CellScene, share: RowShare) -> Result<WallCoupling, CellStepError> {
    let fail = |e: String| CellStepError {
        cell: None,
        source: TimestepError::Wall(e),
    };
    let mut walls = vec![];
    // A tube container carrying a tube flow, or a channel carrying a channel flow, moves with
    // it (in at one end, out at the other);
    // a wall with an angular velocity turns in place; a grid wall moves as its velocity file
    // says; every other wall is at rest.
    let mut velocity = vec![];
    for (k, w) in scene.walls.iter().enumerate() {
        let surface = w.surface().map_err(|e| fail(format!("wall {k}: {e}")))?;
        let wall = Wall::new(w.kind, surface).map_err(|e| fail(format!("wall {k}: {e}")))?;
        let n = wall.n_points();
        let mut u = vec![0.0; 3 * n];
        if let (Flow::Tube { .. }, WallShape::Tube { .. }, WallKind::Container)
        | (Flow::Channel { .. }, WallShape::Channel { .. }, WallKind::Container) =
            (scene.flow, &w.shape, w.kind)
        {
            for (j, &x) in wall.geometry().x.iter().enumerate() {
                let v = scene.flow.velocity(x);
                for a in 0..3 {
                    u[a * n + j] = v[a];
                }
            }
        }
        // A grid wall's own velocity, given at the points of its grid.
        if let Some(v) = w
            .grid_velocity()
            .map_err(|e| fail(format!("wall {k}: {e}")))?
        {
            if v.len() != u.len() {
                return Err(fail(format!(
                    "wall {k}: {} velocity values for {} wall points",
                    v.len() / 3,
                    n
                )));
            }
            for (uj, vj) in u.iter_mut().zip(v) {
                *uj += vj;
            }
        }
        // A turning wall: Ω × (x − c), tangential (checked when the scene was read).
        let (om, c) = (w.angular_velocity, w.center);
        if om != [0.0; 3] {
            for (j, &x) in wall.geometry().x.iter().enumerate() {
                let v = cross3(om, sub3(x, c));
                for a in 0..3 {
                    u[a * n + j] += v[a];
                }
            }
        }
        velocity.extend(u);
        walls.push(wall);
    }
    WallCoupling::new_share(
        walls,
        Some(velocity),
        scene.viscosity,
        WallParams::default(),
        share,
    )
    .map_err(|source| CellStepError { cell: None, source })
}

/// The scene's effects, and the cells' own preconditioners where [`memory_plan`] left them
/// out.
pub(super) fn run_effects(scene: &CellScene, susp: &Suspension) -> Vec<Effect> {
    let mut effects = scene.effects.clone();
    if let (Preconditioning::Cell { .. }, Some(Preconditioning::Sphere)) =
        (scene.numerics.preconditioning, susp.preconditioning())
    {
        let (cells, p) = (scene.cells.len(), scene.numerics.order);
        let bytes = cells as f64 * cell_preconditioner::bytes_per_cell(p) as f64;
        let reason = if susp.operator_storage() == Some(OperatorStorage::MatrixFree) {
            "matrix-free operators keep the sphere's preconditioner".to_string()
        } else {
            format!(
                "the own preconditioners of {cells} cells at p = {p} need {:.1} GB, more than \
                 60 % of the available memory allows beside the operators: every cell takes \
                 the sphere's",
                bytes / 1e9
            )
        };
        effects.push(Effect {
            name: "cell_preconditioner",
            enabled: false,
            reason,
        });
    }
    effects
}

/// Where the cells' operators and preconditioners are kept, within 60 % of the available
/// memory (8 GiB where it is unknown): the scene's choices, except where they do not fit.
/// The cells' own preconditioners ((4 n_c)² doubles each, 3.6 MB at `p = 12`) are kept per
/// cell; where those of all cells do not fit, or leave room only for matrix-free operators
/// (which do without them), every cell takes the sphere's (shared by the cells of one size;
/// the summary says so). Then the fastest operator storage that fits what is left
/// ([`OperatorStorage::for_budget`]: the grid wherever the threads can hold its operators).
pub(super) fn memory_plan(
    scene: &CellScene,
    cells: usize,
    contrast: bool,
) -> (OperatorStorage, Preconditioning) {
    let p = scene.numerics.order;
    let budget = available_memory().map_or(8 << 30, |m| m / 10 * 6);
    let threads = rayon::current_num_threads();
    let auto =
        |budget| OperatorStorage::for_budget(cells, threads, p, 1 + usize::from(contrast), budget);
    let own = cells as u64 * cell_preconditioner::bytes_per_cell(p) as u64;
    if let Preconditioning::Cell { .. } = scene.numerics.preconditioning {
        // The own preconditioners first; matrix-free operators would drop them anyway.
        if own <= budget {
            let storage = scene
                .numerics
                .operator_storage
                .unwrap_or_else(|| auto(budget - own));
            if storage != OperatorStorage::MatrixFree {
                return (storage, scene.numerics.preconditioning);
            }
        }
    }
    let storage = scene
        .numerics
        .operator_storage
        .unwrap_or_else(|| auto(budget));
    (storage, Preconditioning::Sphere)
}

/// `MemAvailable` of `/proc/meminfo` in bytes (`None` where there is none).
pub(super) fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}
