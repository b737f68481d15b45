//! The forces on the vertices and the solvent from the cells: the membranes' own, the
//! solvent–vertex pairs, the inner viscosity, the contacts between cells, the body force and the
//! external forces (see the parent module's "The model").

use super::*;

impl DpdSuspension {
    /// The membranes' own forces, the solvent–vertex pairs, the inner viscosity, the contacts
    /// between cells, the body force on the vertices and the external forces, added to the
    /// fluid's forces (already holding the solvent pairs) and stored for the vertices.
    pub(super) fn add_coupling_forces(&mut self) -> Result<(), DpdError> {
        let params = self.fluid.params;
        let (dt, l, rc) = (params.dt, params.box_len, params.pair.rc);
        let kbt = params.pair.kbt;
        let step = self.fluid.step;
        let cp = self.coupling;
        let key = step_key(params.seed ^ SALT_COUPLING, step);
        let inv_sqrt_dt = 1.0 / dt.sqrt();
        let t0 = std::time::Instant::now();
        // Each cell's own forces, cells in parallel (each writes only its own vertices).
        let body = self.fluid.body;
        let membrane_seed = mix64(params.seed ^ SALT_MEMBRANE);
        let own: Vec<Result<(), DpdError>> = self
            .cells
            .par_iter_mut()
            .enumerate()
            .map(|(ci, c)| {
                c.f.iter_mut().for_each(|f| *f = [0.0; 3]);
                c.membrane.add_forces(&c.x, &mut c.f)?;
                c.membrane.add_viscous_forces(
                    &c.x,
                    &c.v,
                    step,
                    membrane_seed.wrapping_add(ci as u64),
                    dt,
                    &mut c.f,
                )?;
                let nv = c.x.len() as f64;
                // Body force (per particle, as on the solvent) and the external force.
                for (x, f) in c.x.iter().zip(c.f.iter_mut()) {
                    let g = match body {
                        BodyForce::None => [0.0; 3],
                        BodyForce::Constant(g) => g,
                        BodyForce::ReversePoiseuille { force } => {
                            let z = wrap(*x, l)[2];
                            [if z < 0.5 * l[2] { force } else { -force }, 0.0, 0.0]
                        }
                    };
                    for k in 0..3 {
                        f[k] += g[k] + c.external[k] / nv;
                    }
                }
                Ok(())
            })
            .collect();
        // The first failure by cell index, as a serial loop would report it.
        own.into_iter().collect::<Result<(), DpdError>>()?;
        let t1 = std::time::Instant::now();
        self.timings.membrane_s += (t1 - t0).as_secs_f64();
        let mut counter = [0.0; 3];
        for c in &self.cells {
            for k in 0..3 {
                counter[k] += c.external[k];
            }
        }
        // Solvent–vertex pairs, blocks of a cell's vertices in parallel: each block sums its
        // vertices' forces and lists its contributions to the solvent, which are then added
        // block by block in the order of a serial loop (the same sums bit for bit at any
        // thread count).
        let (cells_list, p, [fx, fy, fz]) = self.fluid.split_for_coupling();
        let (grid, starts) = (&cells_list.grid, &cells_list.starts);
        let weight = |w: f64| crate::dpd::pair_force::weight_r(cp.power, w);
        let owner = &self.owner;
        let mut blocks = Vec::new();
        for (ci, c) in self.cells.iter_mut().enumerate() {
            let chunks = c.x.chunks(VERTEX_BLOCK).zip(c.v.chunks(VERTEX_BLOCK));
            for (k, ((x, v), f)) in chunks.zip(c.f.chunks_mut(VERTEX_BLOCK)).enumerate() {
                blocks.push((ci as u32, c.id0 + (k * VERTEX_BLOCK) as u32, x, v, f));
            }
        }
        self.solvent_kicks.resize_with(blocks.len(), Vec::new);
        let kick_lists = &mut self.solvent_kicks[..blocks.len()];
        blocks
            .into_par_iter()
            .zip(kick_lists.par_iter_mut())
            .for_each(|((ci, vid0, xs, vs, fs), kicks)| {
                kicks.clear();
                for (vi, (x, (v, f))) in xs.iter().zip(vs.iter().zip(fs.iter_mut())).enumerate() {
                    let xw = wrap(*x, l);
                    let vid = vid0 + vi as u32;
                    for (nc, s) in grid.neighbours(grid.cell_of(xw)) {
                        for j in starts[nc]..starts[nc + 1] {
                            let d = [
                                xw[0] - (p.x[j] + s[0]),
                                xw[1] - (p.y[j] + s[1]),
                                xw[2] - (p.z[j] + s[2]),
                            ];
                            let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                            if r2 >= rc * rc || r2 == 0.0 {
                                continue;
                            }
                            let r = r2.sqrt();
                            let w = 1.0 - r / rc;
                            let wr = weight(w);
                            let gamma = if owner[p.id[j] as usize] == ci {
                                cp.gamma_in
                            } else {
                                cp.gamma_out
                            };
                            let ve = ((v[0] - p.vx[j]) * d[0]
                                + (v[1] - p.vy[j]) * d[1]
                                + (v[2] - p.vz[j]) * d[2])
                                / r;
                            let sigma = (2.0 * gamma * kbt).sqrt();
                            let fm = (-gamma * wr * wr * ve
                                + sigma * wr * pair_noise(key, vid, p.id[j]) * inv_sqrt_dt)
                                / r;
                            let fd = [fm * d[0], fm * d[1], fm * d[2]];
                            for k in 0..3 {
                                f[k] += fd[k];
                            }
                            kicks.push((j as u32, [-fd[0], -fd[1], -fd[2]]));
                        }
                    }
                }
            });
        add_kicks(kick_lists, [&mut fx[..], &mut fy[..], &mut fz[..]]);
        if counter.iter().any(|&c| c != 0.0) {
            spread_over_outer_solvent(p, &self.owner, counter, [&mut *fx, &mut *fy, &mut *fz]);
        }
        // A more viscous inner fluid: extra dissipative + random pairs among the inner
        // solvent of each cell (independent noise).
        if cp.inner_extra_gamma > 0.0 {
            // Each cell's inner solvent is its own, so the cells run in parallel; their
            // contributions are added in the order of a serial loop.
            let key_in = step_key(params.seed ^ SALT_INNER, step);
            let sigma = (2.0 * cp.inner_extra_gamma * kbt).sqrt();
            let pair = params.pair;
            self.solvent_kicks
                .par_iter_mut()
                .zip(self.cells.par_iter())
                .enumerate()
                .for_each_init(Vec::new, |near, (ci, (kicks, c))| {
                    kicks.clear();
                    let (lo, hi) = bbox(&c.x);
                    particles_near(cells_list, lo, hi, near);
                    let members: Vec<usize> = near
                        .iter()
                        .copied()
                        .filter(|&i| owner[p.id[i] as usize] == ci as u32)
                        .collect();
                    for (a, &i) in members.iter().enumerate() {
                        for &j in &members[a + 1..] {
                            let d = minimum_image(
                                [p.x[i], p.y[i], p.z[i]],
                                [p.x[j], p.y[j], p.z[j]],
                                l,
                            );
                            let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                            if r2 >= rc * rc || r2 == 0.0 {
                                continue;
                            }
                            let r = r2.sqrt();
                            let wr = pair.weight_r(1.0 - r / rc);
                            let ve = ((p.vx[i] - p.vx[j]) * d[0]
                                + (p.vy[i] - p.vy[j]) * d[1]
                                + (p.vz[i] - p.vz[j]) * d[2])
                                / r;
                            let fm = (-cp.inner_extra_gamma * wr * wr * ve
                                + sigma * wr * pair_noise(key_in, p.id[i], p.id[j]) * inv_sqrt_dt)
                                / r;
                            let fd = [fm * d[0], fm * d[1], fm * d[2]];
                            kicks.push((i as u32, fd));
                            kicks.push((j as u32, [-fd[0], -fd[1], -fd[2]]));
                        }
                    }
                });
            let per_cell = &self.solvent_kicks[..self.cells.len()];
            add_kicks(per_cell, [&mut fx[..], &mut fy[..], &mut fz[..]]);
        }
        // Contact repulsion between vertices of different cells (pairs of cells in parallel,
        // added in the order of a serial loop).
        if cp.contact_a > 0.0 && self.cells.len() > 1 {
            let (xs, mut fs): (Vec<Vertices<'_>>, Vec<VertexForces<'_>>) = self
                .cells
                .iter_mut()
                .map(|c| (c.x.as_slice(), c.f.as_mut_slice()))
                .unzip();
            add_contact_forces(&xs, &mut fs, l, rc, cp.contact_a);
        }
        self.timings.coupling_s += t1.elapsed().as_secs_f64();
        if let Some((ci, vi)) = self.cells.iter().enumerate().find_map(|(ci, c)| {
            c.f.iter()
                .position(|f| f.iter().any(|v| !v.is_finite()))
                .map(|vi| (ci, vi))
        }) {
            let x = self.cells[ci].x[vi];
            return Err(DpdError::Unstable {
                step,
                particle: (self.cells[ci].id0 as usize) + vi,
                position: x,
            });
        }
        Ok(())
    }
}

/// Add the per-cell lists of solvent force contributions `(particle, force)` to the solvent's
/// forces, cell by cell and in list order (the order of a serial loop over cells).
fn add_kicks(kicks: &[Vec<(u32, [f64; 3])>], [fx, fy, fz]: [&mut [f64]; 3]) {
    for list in kicks {
        for &(j, d) in list {
            let j = j as usize;
            fx[j] += d[0];
            fy[j] += d[1];
            fz[j] += d[2];
        }
    }
}
