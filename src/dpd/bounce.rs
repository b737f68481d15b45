//! The bounce-back of the solvent off moving membranes ([`super::suspension`], "Bounce-back"):
//! the triangles swept over a step, a particle's path and its earliest collision, and the
//! impulse that reverses the relative velocity while conserving momentum and kinetic energy.
#![allow(clippy::needless_range_loop)]

use super::cell_list::CellList;
use super::contact::bbox;
use super::crossing::first_crossing;
use super::fluid_cell::{image_near, FluidCell};
use super::pair_force::Particles;
use crate::linalg3::{cross3, sub3};

/// Collisions of one particle with membranes followed within one step.
pub(crate) const MAX_BOUNCES: usize = 4;

/// A membrane's swept bounding box over the step, and a bin grid of side `r_c` over it holding
/// the triangles whose swept boxes touch each bin.
pub(crate) struct SweptMembrane {
    pub(crate) lo: [f64; 3],
    pub(crate) hi: [f64; 3],
    pub(crate) centre: [f64; 3],
    pub(crate) dims: [usize; 3],
    pub(crate) rc: f64,
    pub(crate) bins: Vec<Vec<u32>>,
}

impl SweptMembrane {
    pub(crate) fn new(c: &FluidCell, rc: f64, l: [f64; 3]) -> Self {
        let (lo0, hi0) = bbox(&c.x_old);
        let (lo1, hi1) = bbox(&c.x);
        let lo = [0, 1, 2].map(|k| lo0[k].min(lo1[k]) - 1e-9);
        let hi = [0, 1, 2].map(|k| hi0[k].max(hi1[k]) + 1e-9);
        let centre = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        // (The drift check bounds the box; the cap keeps the grid small regardless.)
        let dims = [0, 1, 2]
            .map(|k| (((hi[k] - lo[k]) / rc).ceil() as usize).clamp(1, (l[k] / rc) as usize + 2));
        let mut sw = SweptMembrane {
            lo,
            hi,
            centre,
            dims,
            rc,
            bins: vec![Vec::new(); dims[0] * dims[1] * dims[2]],
        };
        for (t, tri) in c.membrane.topology().triangles().iter().enumerate() {
            let pts = [0, 1, 2].map(|j| [c.x_old[tri[j]], c.x[tri[j]]]);
            let flat: Vec<[f64; 3]> = pts.iter().flatten().copied().collect();
            let (tl, th) = bbox(&flat);
            let (b0, b1) = (sw.bin_of(tl), sw.bin_of(th));
            for bz in b0[2]..=b1[2] {
                for by in b0[1]..=b1[1] {
                    for bx in b0[0]..=b1[0] {
                        let at = sw.bin_index([bx, by, bz]);
                        sw.bins[at].push(t as u32);
                    }
                }
            }
        }
        sw
    }

    pub(crate) fn bin_of(&self, p: [f64; 3]) -> [usize; 3] {
        [0, 1, 2].map(|k| {
            (((p[k] - self.lo[k]) / self.rc).floor().max(0.0) as usize).min(self.dims[k] - 1)
        })
    }

    pub(crate) fn bin_index(&self, b: [usize; 3]) -> usize {
        (b[2] * self.dims[1] + b[1]) * self.dims[0] + b[0]
    }

    /// The path of a particle at `x1` with velocity `v` over the step (`x1 − dt v → x1`),
    /// as the image nearest the membrane, and the shift of that image.
    pub(crate) fn path(&self, x1: [f64; 3], v: [f64; 3], dt: f64, l: [f64; 3]) -> PathImage {
        let x0 = [0, 1, 2].map(|k| x1[k] - dt * v[k]);
        let q0 = image_near(x0, self.centre, l);
        let shift = [0, 1, 2].map(|k| q0[k] - x0[k]);
        let q1 = [0, 1, 2].map(|k| x1[k] + shift[k]);
        let meets = !(0..3).any(|k| q0[k].max(q1[k]) < self.lo[k] || q0[k].min(q1[k]) > self.hi[k]);
        PathImage {
            q0,
            q1,
            shift,
            meets,
        }
    }

    /// The moving particles in the cells of the cell list around the swept box, in the cell
    /// list's order: those that may hit this membrane (a particle moves far less than a cell,
    /// `r_c`, in a step since the last sort).
    pub(crate) fn candidates(
        &self,
        cells: &CellList,
        p: &Particles,
        near: &mut Vec<usize>,
    ) -> Vec<u32> {
        particles_near(cells, self.lo, self.hi, near);
        near.iter()
            .copied()
            .filter(|&i| p.moves[i] != 0.0)
            .map(|i| i as u32)
            .collect()
    }
}

/// A particle's path over the step as the image nearest a membrane.
pub(crate) struct PathImage {
    pub(crate) q0: [f64; 3],
    pub(crate) q1: [f64; 3],
    pub(crate) shift: [f64; 3],
    pub(crate) meets: bool,
}

/// What a collision of a solvent particle with a membrane triangle needs.
pub(crate) struct Collision {
    pub(crate) dt: f64,
    pub(crate) box_len: [f64; 3],
    pub(crate) ms: f64,
    pub(crate) mv: f64,
    pub(crate) rc: f64,
}

impl Collision {
    /// Whether the path of the particle at `x1` with velocity `v` crosses the membrane of `c`
    /// (what [`Self::follow`] finds before its first collision; read-only).
    pub(crate) fn hits(
        &self,
        c: &FluidCell,
        sw: &SweptMembrane,
        x1: [f64; 3],
        v: [f64; 3],
    ) -> bool {
        let path = sw.path(x1, v, self.dt, self.box_len);
        path.meets && earliest_hit(c, sw, path.q0, path.q1, 0.0).is_some()
    }

    /// Follow the path of the particle at `x1` with velocity `v` (after the drift) through
    /// up to [`MAX_BOUNCES`] collisions with the membrane of `c` (whose vertices take the
    /// impulses): the particle's new position and velocity and the number of collisions, or
    /// `None` if it hit nothing.
    pub(crate) fn follow(
        &self,
        c: &mut FluidCell,
        sw: &SweptMembrane,
        x1: [f64; 3],
        v: [f64; 3],
    ) -> Option<([f64; 3], [f64; 3], u64)> {
        let Collision {
            dt,
            box_len: l,
            ms,
            mv,
            rc,
        } = *self;
        let PathImage {
            q0,
            q1,
            shift,
            meets,
        } = sw.path(x1, v, dt, l);
        if !meets {
            return None;
        }
        let tris = c.membrane.topology().triangles();
        // The path is followed through up to MAX_BOUNCES collisions: after each, the rest of
        // the step (from the collision point at fraction `t0` to the end) is tested again
        // against the triangles moving from their positions at `t0` to their ends, so that a
        // particle bounced near an edge cannot slip through the neighbouring triangle.
        let (mut s0, mut s1, mut t0, mut vel) = (q0, q1, 0.0f64, v);
        let mut bounces = 0;
        for _ in 0..MAX_BOUNCES {
            let Some((hit, t)) = earliest_hit(c, sw, s0, s1, t0) else {
                break;
            };
            let tri = tris[t];
            let lam = hit.bary;
            let t_hit = t0 + hit.t * (1.0 - t0);
            // Velocity of the triangle's point over the step, and the point at the end of the
            // step.
            let mut u = [0.0; 3];
            let mut q = [0.0; 3];
            for (j, &vtx) in tri.iter().enumerate() {
                for k in 0..3 {
                    u[k] += lam[j] * (c.x[vtx][k] - c.x_old[vtx][k]) / dt;
                    q[k] += lam[j] * c.x[vtx][k];
                }
            }
            // The collision with the triangle's point (see `collision_impulse`), whose
            // velocity now is Σλ_k v_k (the vertices' current velocities: an earlier collision
            // in this step may have changed them since they drifted with `u`), so that every
            // collision conserves energy; `u` places the particle.
            let mut up = [0.0; 3];
            for (j, &vtx) in tri.iter().enumerate() {
                for k in 0..3 {
                    up[k] += lam[j] * c.v[vtx][k];
                }
            }
            let jmp = collision_impulse([0, 1, 2].map(|k| vel[k] - up[k]), lam, ms, mv);
            let w = [0, 1, 2].map(|k| vel[k] - u[k]);
            for k in 0..3 {
                vel[k] += jmp[k] / ms;
            }
            for (j, &vtx) in tri.iter().enumerate() {
                for k in 0..3 {
                    c.v[vtx][k] -= lam[j] * jmp[k] / mv;
                }
            }
            bounces += 1;
            // The unit normal towards the side the particle came from, at the hit and at the
            // end of the step.
            let normal = |pts: [[f64; 3]; 3]| {
                let n = cross3(sub3(pts[1], pts[0]), sub3(pts[2], pts[0]));
                let nn = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                n.map(|c| hit.side * c / nn)
            };
            let n_hit =
                normal(tri.map(|j| {
                    [0, 1, 2].map(|k| c.x_old[j][k] + t_hit * (c.x[j][k] - c.x_old[j][k]))
                }));
            let n_end = normal(tri.map(|j| c.x[j]));
            // The rest of the step: away from the triangle's point with the reversed relative
            // velocity −w (riding with the point if that is not away from the plane), a small
            // step off the plane on the particle's side.
            let rest = (1.0 - t_hit) * dt;
            let away = -(w[0] * n_end[0] + w[1] * n_end[1] + w[2] * n_end[2]);
            let eps = 1e-7 * rc;
            let hit_point = [0, 1, 2].map(|k| s0[k] + hit.t * (s1[k] - s0[k]));
            s0 = [0, 1, 2].map(|k| hit_point[k] + eps * n_hit[k]);
            s1 = [0, 1, 2].map(|k| {
                let off = if away > 0.0 { -rest * w[k] } else { 0.0 };
                q[k] + off + eps * n_end[k]
            });
            t0 = t_hit;
        }
        (t0 > 0.0).then(|| ([0, 1, 2].map(|k| s1[k] - shift[k]), vel, bounces))
    }
}

/// The earliest crossing of the path `s0 → s1` (the part of the step from the fraction `t0`
/// on) with the triangles of `c`'s membrane near it, each moving from its position at `t0` to
/// its end, and that triangle's index. Reads the vertices' positions only (a collision changes
/// their velocities), so whether a particle's path crosses the membrane does not depend on the
/// collisions of other particles in the same step.
pub(crate) fn earliest_hit(
    c: &FluidCell,
    sw: &SweptMembrane,
    s0: [f64; 3],
    s1: [f64; 3],
    t0: f64,
) -> Option<(super::crossing::Crossing, usize)> {
    let tris = c.membrane.topology().triangles();
    let (pl, ph) = bbox(&[s0, s1]);
    let (b0, b1) = (sw.bin_of(pl), sw.bin_of(ph));
    let at = |j: usize| -> [f64; 3] {
        [0, 1, 2].map(|k| c.x_old[j][k] + t0 * (c.x[j][k] - c.x_old[j][k]))
    };
    let mut best: Option<(super::crossing::Crossing, usize)> = None;
    for bz in b0[2]..=b1[2] {
        for by in b0[1]..=b1[1] {
            for bx in b0[0]..=b1[0] {
                for &t in &sw.bins[sw.bin_index([bx, by, bz])] {
                    let tri = tris[t as usize];
                    let tri0 = tri.map(at);
                    let tri1 = tri.map(|j| c.x[j]);
                    if let Some(hit) = first_crossing(s0, s1, tri0, tri1) {
                        if best.is_none_or(|(b, _)| hit.t < b.t) {
                            best = Some((hit, t as usize));
                        }
                    }
                }
            }
        }
    }
    best
}

/// The impulse `J` on a particle of mass `ms` hitting the point of barycentric coordinates
/// `lam` of a triangle whose vertices have mass `mv`, with relative velocity `w = v − u`: the
/// point's effective mass is `M = m_v/Σλ²`, and `J = −2μw` (`μ = m_s M/(m_s + M)`) reverses
/// the relative velocity while conserving momentum (the vertices take `−λ_k J`) and kinetic
/// energy.
pub(crate) fn collision_impulse(w: [f64; 3], lam: [f64; 3], ms: f64, mv: f64) -> [f64; 3] {
    let lam2 = lam[0] * lam[0] + lam[1] * lam[1] + lam[2] * lam[2];
    let big_m = mv / lam2;
    let mu = ms * big_m / (ms + big_m);
    w.map(|c| -2.0 * mu * c)
}

/// The particles (indices into the sorted arrays) of the cells of `cells` that overlap the box
/// `[lo, hi]` widened by one cell on every side, periodic images included, into `out`: every
/// particle within a cell side of the box at the last sort.
pub(crate) fn particles_near(cells: &CellList, lo: [f64; 3], hi: [f64; 3], out: &mut Vec<usize>) {
    out.clear();
    let g = &cells.grid;
    let range = |k: usize| -> Vec<usize> {
        let n = g.dims[k] as i64;
        let a = (lo[k] * g.inv_cell[k]).floor() as i64 - 1;
        let b = (hi[k] * g.inv_cell[k]).floor() as i64 + 1;
        if b - a + 1 >= n {
            (0..g.dims[k]).collect()
        } else {
            (a..=b).map(|c| c.rem_euclid(n) as usize).collect()
        }
    };
    let (rx, ry, rz) = (range(0), range(1), range(2));
    for &cz in &rz {
        for &cy in &ry {
            for &cx in &rx {
                let c = (cz * g.dims[1] + cy) * g.dims[0] + cx;
                out.extend(cells.starts[c]..cells.starts[c + 1]);
            }
        }
    }
}
