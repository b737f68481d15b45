//! One step of a suspension: the caller's forces evaluated on every cell, the coupling's
//! velocities (explicit, or near cells inside one joint solve), every cell's own solve, and the
//! contact projection at the end (see the parent module for the splitting).

use super::*;

impl Suspension {
    /// The tractions of the caller's `forces` on every cell held here at the start of a step
    /// at `time` (order-`p` grid, `3n` each).
    fn user_tractions(
        &mut self,
        time: f64,
        forces: &[&dyn CellForce],
    ) -> Result<Vec<Vec<f64>>, CellStepError> {
        self.cells
            .par_iter_mut()
            .map(|cell| {
                let id = cell.id;
                let (st, c) = (&cell.stepper, &cell.state.coefs);
                let mut t = VectorField::zeros(st.n_points());
                st.with_geometry(c, |g| {
                    let view = CellView {
                        id,
                        time,
                        coefs: c,
                        geometry: g,
                    };
                    for f in forces {
                        // A panic in the caller's code becomes this cell's step error.
                        let added = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            f.add_traction(&view, &mut t)
                        }));
                        if let Err(panic) = added {
                            return Err(TimestepError::UserForcePanicked {
                                force: f.name().to_string(),
                                message: panic_message(panic.as_ref()),
                            });
                        }
                    }
                    Ok(())
                })
                .and_then(|r| r)
                .map_err(|source| CellStepError {
                    cell: Some(id),
                    source,
                })?;
                let t = t.into_component_major();
                if t.iter().any(|v| !v.is_finite()) {
                    return Err(CellStepError {
                        cell: Some(id),
                        source: TimestepError::NonFinite {
                            what: "traction of a user force",
                        },
                    });
                }
                Ok(t)
            })
            .collect()
    }

    /// [`Suspension::step_on`] with the caller's `forces` ([`CellForce`]) evaluated at `time`
    /// (the start of the step) on every cell: each force's traction acts through the cell's own
    /// single layer in its step and, through the coupling, on the other cells. Over several
    /// ranks every rank passes the same forces (each evaluates them on its own cells).
    pub fn step_with_forces(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        time: f64,
        forces: &[&dyn CellForce],
    ) -> Result<SuspensionReport, CellStepError> {
        if self.needs_start_up(comm)? {
            self.start_up(comm, u_inf, time, forces)?;
        }
        let report = self.step_once(comm, u_inf, time, forces)?;
        self.recycle(comm)?;
        Ok(report)
    }

    /// One step of [`Suspension::step_with_forces`] from the state as it is.
    pub(super) fn step_once(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        time: f64,
        forces: &[&dyn CellForce],
    ) -> Result<SuspensionReport, CellStepError> {
        let t0 = std::time::Instant::now();
        // (Without forces nothing can fail, and no rank has any: no agreement needed.)
        let user = if forces.is_empty() {
            vec![Vec::new(); self.cells.len()]
        } else {
            agree_cells(comm, self.user_tractions(time, forces))?
        };
        // The densities passed to the coupling (the near-implicit step extrapolates them).
        type Densities = (Vec<Vec<f64>>, Vec<Option<Vec<f64>>>);
        let mut densities: Option<Densities> = None;
        if self.coupling.is_some() || self.walls.is_some() || self.plane.is_some() {
            let tractions: Result<Vec<Vec<f64>>, CellStepError> = self
                .cells
                .par_iter_mut()
                .zip(user.par_iter())
                .map(|(cell, u)| {
                    let mut f = vec![0.0; 3 * cell.stepper.n_points()];
                    cell.stepper
                        .traction(&cell.state, &mut f)
                        .map_err(|source| CellStepError {
                            cell: Some(cell.id),
                            source,
                        })?;
                    for (f, u) in f.iter_mut().zip(u) {
                        *f += u;
                    }
                    Ok(f)
                })
                .collect();
            self.solve_s += t0.elapsed().as_secs_f64();
            let tractions = agree_cells(comm, tractions)?;
            for c in &mut self.cells {
                c.state.previous_velocity = c.state.velocity.take();
            }
            let ids: Vec<usize> = self.cells.iter().map(|c| c.id).collect();
            let cref: Vec<&[f64]> = self.cells.iter().map(|c| &c.state.coefs[..]).collect();
            let fref: Vec<&[f64]> = tractions.iter().map(|c| c.as_slice()).collect();
            // Double-layer densities (1 − λ_j) u_j from each cell's last solve (none before the
            // first step: the first step couples the single layers only).
            let scaled: Vec<Option<Vec<f64>>> = self
                .cells
                .iter()
                .map(|c| {
                    let lambda = c.stepper.params().viscosity_ratio;
                    match &c.state.membrane_velocity {
                        Some(u) if lambda != 1.0 && self.inter_cell_double_layer => {
                            Some(u.iter().map(|v| (1.0 - lambda) * v).collect())
                        }
                        _ => None,
                    }
                })
                .collect();
            let dref: Vec<Option<&[f64]>> = scaled.iter().map(|d| d.as_deref()).collect();
            if let Some(coupling) = &mut self.coupling {
                let velocities = coupling
                    .velocities_on(comm, &ids, &cref, &fref, &dref)
                    .map_err(|source| CellStepError { cell: None, source })?;
                for (c, v) in self.cells.iter_mut().zip(velocities) {
                    c.state.velocity = Some(v);
                }
            }
            self.add_wall_velocities(comm, u_inf, &tractions, &scaled)?;
            self.add_plane_velocities(comm, &tractions, &scaled)?;
            if let Some(record) = &mut self.coupling_record {
                *record = self
                    .cells
                    .iter()
                    .map(|c| c.state.velocity.clone().unwrap_or_default())
                    .collect();
            }
            if self.coupling.is_some() || self.plane.is_some() {
                densities = Some((tractions, scaled));
            }
        }
        // BDF2 takes the explicit terms at X* = (1 + ω)Xⁿ − ωXⁿ⁻¹ (ω = Δtⁿ/Δtⁿ⁻¹):
        // v* = (1 + ω)vⁿ − ωvⁿ⁻¹ (second order; 2vⁿ − vⁿ⁻¹ at a constant step).
        let explicit: Vec<Option<Vec<f64>>> = self
            .cells
            .iter()
            .map(|c| {
                let v = c.state.velocity.as_deref().unwrap_or_default();
                let u = c.state.previous_velocity.as_deref().unwrap_or_default();
                if v.is_empty() {
                    return None;
                }
                let previous = (!u.is_empty()).then_some(u);
                Some(extrapolate(
                    v,
                    previous,
                    c.stepper.extrapolation_ratio(&c.state),
                ))
            })
            .collect();
        let repulsion = self.coupling.as_ref().and_then(|c| c.repulsion());
        // With the caller's forces, the explicit traction of a cell is the contact repulsion
        // plus their tractions (without, the repulsion alone, not copied).
        let combined: Vec<Option<Vec<f64>>> = user
            .into_iter()
            .enumerate()
            .map(|(i, u)| {
                // A cell the caller's forces leave alone takes the repulsion path as before.
                if u.iter().all(|&v| v == 0.0) {
                    return None;
                }
                Some(match repulsion {
                    Some(r) if !r[i].is_empty() => {
                        r[i].iter().zip(&u).map(|(a, b)| a + b).collect()
                    }
                    _ => u,
                })
            })
            .collect();
        let t1 = std::time::Instant::now();
        let traction_of = |i: usize| {
            combined[i]
                .as_deref()
                .or_else(|| repulsion.map(|r| r[i].as_slice()))
        };
        let reports: Result<Vec<StepReport>, CellStepError> = match (self.coupling_mode, &densities)
        {
            (CouplingMode::NearImplicit, Some((tractions, scaled))) => {
                let with_dl = self.inter_cell_double_layer;
                let ids: Vec<usize> = self.cells.iter().map(|c| c.id).collect();
                // ρⁿ goes into the state before the step, so that the step's reparametrisation
                // relabels it with the grid; ρⁿ⁻¹ comes out for the extrapolation.
                let previous: Vec<Option<Vec<f64>>> = self
                    .cells
                    .iter_mut()
                    .zip(tractions)
                    .zip(scaled)
                    .map(|((c, f), g)| {
                        let mut rho = f.clone();
                        match g {
                            Some(g) => rho.extend_from_slice(g),
                            None => rho.resize(2 * f.len(), 0.0),
                        }
                        c.state.previous_density.replace(rho)
                    })
                    .collect();
                let mut joint: Vec<JointCell<'_>> = self
                    .cells
                    .iter_mut()
                    .enumerate()
                    .map(|(i, c)| JointCell {
                        stepper: &mut c.stepper,
                        state: &mut c.state,
                        extra: ExplicitTerms {
                            velocity: explicit[i].as_deref(),
                            traction: traction_of(i),
                        },
                        repulsion: repulsion.map(|r| r[i].as_slice()).filter(|r| !r.is_empty()),
                        traction_now: &tractions[i],
                        dl_now: scaled[i].as_deref(),
                        previous: previous[i].as_deref(),
                    })
                    .collect();
                // Over several ranks the statistics are those of all ranks.
                let stepped = step_all_on(comm, &ids, &mut joint, &self.near_pairs, u_inf, with_dl);
                drop(joint);
                match stepped {
                    RanksStep::Done(reports, stats) => {
                        self.joint.merge(&stats);
                        Ok(reports)
                    }
                    RanksStep::Failed(k, source) => Err(CellStepError {
                        cell: k.map(|k| ids[k]),
                        source,
                    }),
                    // Another rank's cell failed: `agree_cells` below returns its error here.
                    RanksStep::Elsewhere => Ok(Vec::new()),
                }
            }
            _ => self
                .cells
                .par_iter_mut()
                .enumerate()
                .map(|(i, cell)| {
                    let extra = ExplicitTerms {
                        velocity: explicit[i].as_deref(),
                        traction: traction_of(i),
                    };
                    cell.stepper
                        .step_with(&mut cell.state, u_inf, extra)
                        .map_err(|source| CellStepError {
                            cell: Some(cell.id),
                            source,
                        })
                })
                .collect(),
        };
        self.solve_s += t1.elapsed().as_secs_f64();
        let reports = agree_cells(comm, reports)?;
        for (c, r) in self.cells.iter_mut().zip(&reports) {
            c.state.iterations = r.gmres.iterations;
        }
        self.resolve_contacts(comm)?;
        Ok(SuspensionReport { cells: reports })
    }
}

/// The text of a caught panic (its `&str` or `String` payload).
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(a panic without a message)".to_string())
}
