//! A cell in the DPD fluid as the fluid sees it: its mesh and parameters ([`CellSpec`]), the
//! test of whether two meshes overlap, and the cell's vertices with what is measured of them
//! ([`FluidCell`]: centroid, velocity, the equivalent ellipsoid, the deformation in the shear
//! plane, the tank-treading phase).

use super::crossing::inside;
use super::membrane::{Membrane, MembraneParams};
use super::DpdError;
use crate::linalg3::{cross3, dot3, sub3};

/// A cell to put into the fluid: its mesh (vertices at their initial, stress-free positions,
/// inside the box or its periodic images; triangles counter-clockwise seen from outside) and
/// its membrane parameters.
#[derive(Clone, Debug)]
pub struct CellSpec {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles.
    pub triangles: Vec<[usize; 3]>,
    /// Membrane parameters.
    pub params: MembraneParams,
}

impl CellSpec {
    /// Whether a vertex of either cell is inside the other, in a periodic box of sides `box_len`
    /// (nearest images); see [`meshes_overlap`].
    pub fn overlaps(&self, other: &CellSpec, box_len: [f64; 3]) -> bool {
        meshes_overlap(
            &self.vertices,
            &self.triangles,
            &other.vertices,
            &other.triangles,
            box_len,
        )
    }
}

/// Whether a vertex of either closed mesh `(va, ta)`, `(vb, tb)` is inside the other (winding
/// number, nearest periodic images in a box of sides `l`); meshes whose bounding spheres about
/// their vertex means are apart are not tested further.
pub fn meshes_overlap(
    va: &[[f64; 3]],
    ta: &[[usize; 3]],
    vb: &[[f64; 3]],
    tb: &[[usize; 3]],
    l: [f64; 3],
) -> bool {
    let extent = |v: &[[f64; 3]], c: [f64; 3]| {
        v.iter()
            .map(|p| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max)
    };
    let (ca, cb) = (mean(va), mean(vb));
    let d = image_near(cb, ca, l);
    let dist = (0..3).map(|k| (d[k] - ca[k]).powi(2)).sum::<f64>().sqrt();
    if dist > extent(va, ca) + extent(vb, cb) {
        return false;
    }
    vb.iter().any(|&p| inside(image_near(p, ca, l), va, ta))
        || va.iter().any(|&p| inside(image_near(p, cb, l), vb, tb))
}

/// One cell in the fluid.
#[derive(Clone, Debug)]
pub struct FluidCell {
    pub(crate) membrane: Membrane,
    /// Vertex positions, unwrapped (continuous in time; images of the box are equivalent).
    pub(crate) x: Vec<[f64; 3]>,
    /// Vertex velocities.
    pub(crate) v: Vec<[f64; 3]>,
    /// Vertex forces at the current positions.
    pub(crate) f: Vec<[f64; 3]>,
    /// Positions at the start of the current step's drift.
    pub(crate) x_old: Vec<[f64; 3]>,
    /// Id of the first vertex (the noise key; ids follow the solvent's).
    pub(crate) id0: u32,
    /// External force on the whole cell (spread evenly over its vertices).
    pub(crate) external: [f64; 3],
}

impl FluidCell {
    /// The membrane (topology, parameters, reference geometry).
    pub fn membrane(&self) -> &Membrane {
        &self.membrane
    }

    /// Vertex positions (unwrapped).
    pub fn positions(&self) -> &[[f64; 3]] {
        &self.x
    }

    /// Vertex velocities.
    pub fn velocities(&self) -> &[[f64; 3]] {
        &self.v
    }

    /// The mean of the vertex positions.
    pub fn centroid(&self) -> [f64; 3] {
        mean(&self.x)
    }

    /// The mean vertex velocity.
    pub fn mean_velocity(&self) -> [f64; 3] {
        mean(&self.v)
    }

    /// The external force on the cell.
    pub fn external_force(&self) -> [f64; 3] {
        self.external
    }

    /// The ellipsoid with the same volume second moments as the membrane's enclosed volume
    /// (`∫_V (x − c)(x − c)ᵀ dV`, summed over the tetrahedra of each triangle with the
    /// centroid `c`; an ellipsoid of semi-axes `a_k` has `V a_k²/5` on its principal axes):
    /// semi-axes `a_k = √(5 λ_k / V)` in descending order, and their unit directions
    /// (`axes[k]` belongs to `semi_axes[k]`).
    pub fn equivalent_ellipsoid(&self) -> ([f64; 3], [[f64; 3]; 3]) {
        let c = self.centroid();
        let mut m = [[0.0; 3]; 3];
        let mut vol = 0.0;
        for t in self.membrane.topology().triangles() {
            let p = t.map(|j| sub3(self.x[j], c));
            let v6 = dot3(p[0], cross3(p[1], p[2]));
            let sum = [0, 1, 2].map(|k| p[0][k] + p[1][k] + p[2][k]);
            vol += v6 / 6.0;
            for i in 0..3 {
                for j in 0..3 {
                    let pp: f64 = p.iter().map(|q| q[i] * q[j]).sum();
                    m[i][j] += v6 / 120.0 * (pp + sum[i] * sum[j]);
                }
            }
        }
        // Ascending eigenvalues; the semi-axes descending.
        let (vals, vecs) = crate::linalg3::symmetric_eigen3(m);
        let order = [2, 1, 0];
        let semi = order.map(|k| (5.0 * vals[k].max(0.0) / vol).sqrt());
        let axes = order.map(|k| vecs[k]);
        (semi, axes)
    }

    /// Taylor deformation and inclination in the shear plane `x`–`z` (vorticity along `y`, as
    /// in Couette flow between plane walls normal to `z` and in periodic Poiseuille flow):
    /// of the [`Self::equivalent_ellipsoid`]'s semi-axes, the one whose axis is closest to
    /// `y` is left out, and of the other two, `L ≥ B`, `D = (L − B)/(L + B)`; the inclination
    /// is the angle of `L`'s axis from `x` towards `z`, in degrees in `[−90, 90]`.
    pub fn shear_plane_deformation(&self) -> (f64, f64) {
        let (semi, axes) = self.equivalent_ellipsoid();
        let (l, b, ax) = crate::linalg3::shear_plane_semi_axes(semi, axes, [0.0, 1.0, 0.0]);
        (
            (l - b) / (l + b),
            crate::linalg3::axis_inclination_deg(ax, 0, 2),
        )
    }

    /// The area of each vertex: a third of the areas of the triangles around it.
    pub fn vertex_areas(&self) -> Vec<f64> {
        let mut a = vec![0.0; self.x.len()];
        for t in self.membrane.topology().triangles() {
            let p = t.map(|j| self.x[j]);
            let n = cross3(sub3(p[1], p[0]), sub3(p[2], p[0]));
            let third = dot3(n, n).sqrt() / 6.0;
            for &j in t {
                a[j] += third;
            }
        }
        a
    }

    /// The membrane's mean phase advance about `axis` since the vertex positions `before`
    /// (an earlier [`Self::positions`]), weighted by today's [`Self::vertex_areas`]
    /// ([`crate::vesicle::tank_treading::phase_advance`]): divided by the time between, the
    /// tank-treading rate over that interval, counter-clockwise about `axis` (pass
    /// `[0, 1, 0]` for the sense of the Couette flow `u = (γ̇z, 0, 0)`).
    ///
    /// # Errors
    /// [`DpdError::Length`] when `before` has a different number of vertices.
    pub fn phase_advance(&self, before: &[[f64; 3]], axis: [f64; 3]) -> Result<f64, DpdError> {
        if before.len() != self.x.len() {
            return Err(DpdError::Length {
                what: "earlier vertex positions",
                len: before.len(),
                expected: self.x.len(),
            });
        }
        Ok(crate::vesicle::tank_treading::phase_advance(
            before,
            &self.x,
            &self.vertex_areas(),
            axis,
        ))
    }

    /// Area and volume now, relative to the reference (stress-free) ones, minus one.
    pub fn area_volume_change(&self) -> Result<(f64, f64), DpdError> {
        let m = &self.membrane;
        Ok((
            m.area(&self.x)? / m.area0() - 1.0,
            m.volume(&self.x)? / m.volume0() - 1.0,
        ))
    }
}

pub(crate) fn mean(v: &[[f64; 3]]) -> [f64; 3] {
    let n = v.len().max(1) as f64;
    let mut s = [0.0; 3];
    for p in v {
        for k in 0..3 {
            s[k] += p[k];
        }
    }
    s.map(|c| c / n)
}

/// `p` wrapped into `[0, L)`.
pub(crate) fn wrap(p: [f64; 3], l: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| {
        let w = p[k].rem_euclid(l[k]);
        if w >= l[k] {
            0.0
        } else {
            w
        }
    })
}

/// The periodic image of `p` nearest `centre`.
pub(crate) fn image_near(p: [f64; 3], centre: [f64; 3], l: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| p[k] - l[k] * ((p[k] - centre[k]) / l[k]).round())
}
