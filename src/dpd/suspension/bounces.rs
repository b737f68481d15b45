//! The solvent bounced back off the moving membranes, and the vertices off the wall (see the
//! parent module's "The model"): which side of each membrane every particle is on, and the
//! bounces of one step.

use super::*;

impl DpdSuspension {
    /// The cell each solvent id is inside now (`OUTSIDE` if none), by the winding number of
    /// each membrane over the particles near it. Vertex ids (above the solvent's) are
    /// `OUTSIDE`.
    pub(super) fn sides(&self) -> Vec<u32> {
        let p = &self.fluid.particles;
        let l = self.fluid.params.box_len;
        // The ids inside each membrane, cells in parallel; written in cell order, so a
        // particle found inside two membranes (a leak) takes the later cell, as in a serial loop.
        let inside_ids: Vec<Vec<u32>> = self
            .cells
            .par_iter()
            .map_init(Vec::new, |near, c| {
                let (lo, hi) = bbox(&c.x);
                let centre = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
                let tris = c.membrane.topology().triangles();
                particles_near(self.fluid.cell_list(), lo, hi, near);
                near.iter()
                    .filter(|&&i| p.moves[i] != 0.0)
                    .filter(|&&i| {
                        let q = image_near([p.x[i], p.y[i], p.z[i]], centre, l);
                        !(0..3).any(|k| q[k] < lo[k] || q[k] > hi[k]) && inside(q, &c.x, tris)
                    })
                    .map(|&i| p.id[i])
                    .collect()
            })
            .collect();
        let mut out = vec![OUTSIDE; self.owner.len()];
        for (ci, ids) in inside_ids.iter().enumerate() {
            for &id in ids {
                out[id as usize] = ci as u32;
            }
        }
        out
    }

    /// Bounce the solvent particles whose drift crossed a membrane (see the module docs).
    ///
    /// The cells run in parallel for the particles near one cell only (each such particle and
    /// each cell's vertices are touched by one task; the particles are taken in the cell
    /// list's order, as a serial loop would); the particles near several cells follow, cell by
    /// cell in order, each cell seeing the bounces of the ones before. The result does not
    /// depend on the thread count, and with cells apart it is the serial loop's.
    pub(super) fn bounce_off_membranes(&mut self) {
        let (dt, l) = (self.fluid.params.dt, self.fluid.params.box_len);
        let rc = self.fluid.params.pair.rc;
        let collision = Collision {
            dt,
            box_len: l,
            ms: self.fluid.params.mass,
            mv: self.coupling.vertex_mass,
            rc,
        };
        let swept: Vec<SweptMembrane> = self
            .cells
            .par_iter()
            .map(|c| SweptMembrane::new(c, rc, l))
            .collect();
        let (cells_list, p) = (self.fluid.cell_list(), &self.fluid.particles);
        let candidates: Vec<Vec<u32>> = swept
            .par_iter()
            .map_init(Vec::new, |near, sw| sw.candidates(cells_list, p, near))
            .collect();
        // Near how many cells each particle is.
        let count = &mut self.bounce_count;
        count.clear();
        count.resize(p.len(), 0);
        for list in &candidates {
            for &i in list {
                count[i as usize] = count[i as usize].saturating_add(1);
            }
        }
        let count = &self.bounce_count;
        // Particles near one cell only: cells in parallel, the new states applied after.
        let moved: Vec<(Vec<Bounced>, u64)> = self
            .cells
            .par_iter_mut()
            .zip(swept.par_iter())
            .zip(candidates.par_iter())
            .map(|((c, sw), list)| {
                let (mut out, mut n) = (Vec::new(), 0);
                // The particles whose paths cross the membrane, found in parallel (the test
                // reads positions only); only they are followed, in the list's order, as the
                // serial loop over the whole list would.
                let cell: &FluidCell = c;
                let hitting: Vec<u32> = list
                    .par_iter()
                    .copied()
                    .filter(|&i| {
                        let i = i as usize;
                        count[i] == 1
                            && collision.hits(
                                cell,
                                sw,
                                [p.x[i], p.y[i], p.z[i]],
                                [p.vx[i], p.vy[i], p.vz[i]],
                            )
                    })
                    .collect();
                for i in hitting {
                    let i = i as usize;
                    let (x, v) = ([p.x[i], p.y[i], p.z[i]], [p.vx[i], p.vy[i], p.vz[i]]);
                    if let Some((x, v, b)) = collision.follow(c, sw, x, v) {
                        out.push((i as u32, x, v));
                        n += b;
                    }
                }
                (out, n)
            })
            .collect();
        let p = &mut self.fluid.particles;
        for (list, n) in moved {
            self.bounces += n;
            for (i, x, v) in list {
                let i = i as usize;
                (p.x[i], p.y[i], p.z[i]) = (x[0], x[1], x[2]);
                (p.vx[i], p.vy[i], p.vz[i]) = (v[0], v[1], v[2]);
            }
        }
        // Particles near several cells: cell by cell, each seeing the others' bounces.
        for ((c, sw), list) in self.cells.iter_mut().zip(&swept).zip(&candidates) {
            for &i in list.iter().filter(|&&i| count[i as usize] > 1) {
                let i = i as usize;
                let (x, v) = ([p.x[i], p.y[i], p.z[i]], [p.vx[i], p.vy[i], p.vz[i]]);
                if let Some((x, v, b)) = collision.follow(c, sw, x, v) {
                    (p.x[i], p.y[i], p.z[i]) = (x[0], x[1], x[2]);
                    (p.vx[i], p.vy[i], p.vz[i]) = (v[0], v[1], v[2]);
                    self.bounces += b;
                }
            }
        }
    }

    /// Vertices that drifted into the wall are bounced back like solvent particles.
    pub(super) fn bounce_vertices_off_wall(&mut self) {
        let Some(wall) = self.fluid.wall else { return };
        let dt = self.fluid.params.dt;
        let l = self.fluid.params.box_len;
        let speed = self.fluid.wall_speed;
        for c in &mut self.cells {
            for ((x, xo), v) in c.x.iter_mut().zip(&c.x_old).zip(c.v.iter_mut()) {
                let w = wrap(*x, l);
                if wall.sdf(w) < 0.0 {
                    continue;
                }
                // The path of this step's drift, x_old → x.
                let disp = [0, 1, 2].map(|k| (x[k] - xo[k]) / dt);
                let (wn, _) = wall.bounce(w, disp, dt);
                let uw = crate::dpd::system::wall_velocity(wall, speed, wn);
                for k in 0..3 {
                    x[k] += wn[k] - w[k];
                }
                // The velocity relative to the wall reversed.
                *v = [0, 1, 2].map(|k| 2.0 * uw[k] - v[k]);
            }
        }
    }
}

/// A bounced particle: its index, new position and new velocity.
type Bounced = (u32, [f64; 3], [f64; 3]);
