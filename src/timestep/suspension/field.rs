//! The flow's velocity at arbitrary points, for output (a velocity plane through a vessel).
//!
//! With every cell's traction `f` (the explicit coupling's density, [`CellStepper::traction`]
//! of its state) and double-layer density `g = (1 − λ) u` (`u` the membrane velocity of its last
//! solve; none before the first step or for `λ = 1`), the boundary-integral representation
//! gives the velocity everywhere (Pozrikidis, *Boundary Integral and Singularity Methods*, 1992,
//! §5.3):
//!
//! ```text
//! χ(x) u(x) = u_∞(x) + u_walls(x) + Σ_j ( S_j[f_j](x) + D_j[g_j](x) ),
//! χ = 1 in the suspending fluid,   χ = λ_k inside cell k,
//! ```
//!
//! with the walls' part from the walls' solution of the last step ([`WallCoupling::field_at`]).
//! Between walls each `g` first loses its net normal flux, as the walls were solved for it.
//! Each cell's layers use the coarse smooth rule (order `3p`) where its bounding spheres
//! resolve the target, and elsewhere the near-zone evaluator ([`OffSurface`]), which also says
//! on which side of the membrane the target lies. Its zone is `0.05` of the smallest cell's
//! equivalent radius over all ranks (the same on any number of ranks), with an order
//! `min(32p, 256)` smooth rule beyond it. Points outside the fluid (in a rigid body, beyond a
//! container) get `NaN`.
//!
//! [`CellStepper::traction`]: super::super::cell_stepper::CellStepper::traction
//! [`WallCoupling::field_at`]: super::super::wall_coupling::WallCoupling::field_at

use super::super::image_quadrature::ImageLayers;
use super::super::wall_coupling::{without_net_flux, CellLayers};
use super::super::TimestepError;
use super::{agree_cells, CellStepError, Suspension};
use crate::comm::Communicator;
use crate::vesicle::smooth_layer::{Side, SmoothLayer};
use crate::vesicle::{LayerKernel, NearParams, OffSurface};

/// The near zone of the evaluation, a fraction of the smallest cell's equivalent radius.
const THIN_ZONE: f64 = 0.05;

/// The evaluators of [`Suspension::velocity_at`] for cells of order `p` (near zone `delta`).
pub(super) struct FieldEvaluators {
    p: usize,
    delta: f64,
    near: OffSurface,
    coarse: SmoothLayer,
}

impl Suspension {
    /// The velocity at `targets` (see the module documentation; collective over the ranks of
    /// `comm`, every rank gets the same values, summed in rank order).
    pub fn velocity_at(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        targets: &[[f64; 3]],
    ) -> Result<Vec<[f64; 3]>, CellStepError> {
        let nt = targets.len();
        // The near zone: a fraction of the smallest cell's equivalent radius over all ranks
        // (the same zone on any number of ranks).
        let radii: Result<Vec<f64>, CellStepError> = self
            .cells
            .iter()
            .map(|c| match c.state.drift_targets {
                // The volume the drift correction restores: fixed from the first step on and
                // kept in checkpoints, so that a resumed run sets the same zone.
                Some((_, volume)) => Ok((3.0 * volume / (4.0 * std::f64::consts::PI)).cbrt()),
                None => c
                    .stepper
                    .with_geometry(&c.state.coefs, |g| g.equivalent_radius())
                    .map_err(|source| CellStepError {
                        cell: Some(c.id),
                        source,
                    }),
            })
            .collect();
        let radii = agree_cells(comm, radii)?;
        let mut radius = [radii.into_iter().fold(f64::INFINITY, f64::min)];
        comm.all_min(&mut radius)?;
        // This rank's cells: their layers (component-major) and, per target, the viscosity
        // ratio of the cell it lies in (0: in none of them).
        let mut local = vec![0.0; 4 * nt];
        let mine = self.cells_at(targets, THIN_ZONE * radius[0], &mut local);
        agree_cells(comm, mine)?;
        let gathered = comm.all_gather_f64(&local).map_err(|e| CellStepError {
            cell: None,
            source: TimestepError::Comm(e),
        })?;
        let mut layers = vec![0.0; 3 * nt];
        let mut lambda = vec![0.0_f64; nt];
        for part in &gathered {
            for (s, v) in layers.iter_mut().zip(&part[..3 * nt]) {
                *s += v;
            }
            for (l, v) in lambda.iter_mut().zip(&part[3 * nt..]) {
                *l = l.max(*v);
            }
        }
        // The walls: the same system and solution on every rank.
        let walls = self
            .walls
            .as_mut()
            .map(|w| w.field_at(comm, u_inf, targets))
            .transpose()
            .map_err(|source| CellStepError { cell: None, source });
        let walls = agree_cells(comm, walls)?;
        // A plane wall: the fluid is above it (the images are in the cells' layers).
        let below: Option<Vec<bool>> = self
            .plane
            .as_ref()
            .map(|w| targets.iter().map(|&x| w.wall().height(x) <= 0.0).collect());
        Ok((0..nt)
            .map(|i| {
                let u = u_inf(targets[i]);
                let chi = if lambda[i] > 0.0 { lambda[i] } else { 1.0 };
                if below.as_ref().is_some_and(|b| b[i]) {
                    return [f64::NAN; 3];
                }
                match &walls {
                    Some((_, fluid)) if !fluid[i] => [f64::NAN; 3],
                    w => std::array::from_fn(|a| {
                        let wall = w.as_ref().map_or(0.0, |(v, _)| v[a * nt + i]);
                        (u[a] + wall + layers[a * nt + i]) / chi
                    }),
                }
            })
            .collect())
    }

    /// Add this rank's cells' layers at `targets` to `out[..3 nt]` (component-major) and set
    /// `out[3 nt + i]` to the viscosity ratio of the cell target `i` lies in; `delta` is the
    /// near zone.
    fn cells_at(
        &mut self,
        targets: &[[f64; 3]],
        delta: f64,
        out: &mut [f64],
    ) -> Result<(), CellStepError> {
        let nt = targets.len();
        let Some(first) = self.cells.first() else {
            return Ok(());
        };
        let fail = |cell, source| CellStepError {
            cell: Some(cell),
            source,
        };
        let p = first.stepper.order();
        let viscosity = first.stepper.params().viscosity;
        let vesicle = |cell: usize| move |e| fail(cell, TimestepError::from(e));
        if self
            .field
            .as_ref()
            .is_none_or(|f| f.p != p || f.delta != delta)
        {
            // A narrow near zone with a fine smooth rule beyond it: the default zone (`R/√p`)
            // puts the check points of a target inside an RBC's thin centre (0.29 radii thick)
            // through the far face.
            let params = NearParams {
                near_distance: Some(delta),
                far_order: Some((32 * p).min(256)),
                ..NearParams::default()
            };
            self.field = Some(FieldEvaluators {
                p,
                delta,
                near: OffSurface::new(p, params).map_err(vesicle(first.id))?,
                coarse: SmoothLayer::new(p, 3 * p, 3.0).map_err(vesicle(first.id))?,
            });
        }
        let walls = self.walls.is_some();
        let Suspension {
            cells,
            field,
            plane,
            ..
        } = self;
        let FieldEvaluators { near, coarse, .. } = field.as_mut().expect("built above");
        let sl = LayerKernel::SingleLayer { viscosity };
        let (layers, inside_of) = out.split_at_mut(3 * nt);
        for (slot, c) in cells.iter().enumerate() {
            let id = c.id;
            let lambda = c.stepper.params().viscosity_ratio;
            let mut f = vec![0.0; 3 * c.stepper.n_points()];
            c.stepper
                .traction(&c.state, &mut f)
                .map_err(|e| fail(id, e))?;
            let g: Option<Vec<f64>> = match &c.state.membrane_velocity {
                Some(u) if lambda != 1.0 => Some(u.iter().map(|v| (1.0 - lambda) * v).collect()),
                _ => None,
            };
            // Between walls, the density without its net normal flux, as the walls were
            // solved for it (`wall_coupling::without_net_flux`).
            let g = match g {
                Some(g) if walls => Some(
                    c.stepper
                        .with_geometry(&c.state.coefs, |geom| without_net_flux(geom, &g).0)
                        .map_err(|e| fail(id, e))?,
                ),
                g => g,
            };
            coarse.set_surface(&c.state.coefs).map_err(vesicle(id))?;
            let (mut far, mut close) = (vec![], vec![]);
            for (i, &x) in targets.iter().enumerate() {
                match coarse.side(x) {
                    Side::FarOutside => far.push(i),
                    Side::FarInside => {
                        far.push(i);
                        inside_of[i] = lambda;
                    }
                    Side::Unresolved => close.push(i),
                }
            }
            let cell = CellLayers {
                coefs: &c.state.coefs,
                single_layer: sl,
                traction: &f,
                double_layer: g.as_deref(),
            };
            let infos = cell
                .add_at(coarse, near, targets, (&far, &close), layers)
                .map_err(vesicle(id))?;
            for (&i, info) in close.iter().zip(&infos) {
                if info.inside {
                    inside_of[i] = lambda;
                }
            }
            // A plane wall: the images of this cell's layers, from its present state.
            if let Some(w) = plane {
                let cell = ImageLayers {
                    coefs: &c.state.coefs,
                    traction: &f,
                    double_layer: g.as_deref(),
                };
                w.add_cell_images(slot, p, cell, targets, layers)
                    .map_err(|e| fail(id, e))?;
            }
        }
        Ok(())
    }
}
