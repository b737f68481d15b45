//! Optical tweezers through rigid beads: the ends of a cell bonded to two spheres that carry
//! `±F`, so that each bonded patch keeps the bead's shape instead of being drawn to a point.
//!
//! In the experiments of Mills et al. (Mech. Chem. Biosyst. 1, 2004) and Dao, Lim & Suresh
//! (J. Mech. Phys. Solids 51, 2003) two silica beads of 4.12 µm diameter are bonded to opposite
//! ends of a red cell over a contact of about 2 µm diameter, one held by the trap, one by the
//! glass. The load reaches the membrane only through the bond, and the bonded membrane moves
//! with the bead as one body. [`super::cell_force::SmoothPatchPair`] spreads the same force
//! as a given traction on a patch that is free to deform, which lets the stretched ends grow
//! sharp; here the patch is held on the bead.
//!
//! **The bond.** Each bead is a sphere of radius `r` whose centre `c = c_⊥ + s a` lies on a
//! line along the pull axis `a` through the lateral centre `c_⊥` of its patch (the
//! patch-weighted mean of the points' positions across `a`). The patch is that of
//! [`SmoothPatchPair`] (weights `w_j ∈ [0, 1]` at the grid points, carrying a share of the
//! cell's area at each end). A bonded point is held on the bead's surface by a stiff spring:
//! the traction at point `j` is
//!
//! `t_j = k w_j (r − d_j) (x_j − c)/d_j`, with `d_j = |x_j − c|`,
//!
//! the pull towards its nearest point on the sphere (`k`: traction per unit of misfit, large
//! against the membrane's `G_s/R²`). The bead's axial place `s` is where the bond carries the
//! trap's force, `Σ_j t_j · a dA_j = ±F` (found by bisection: the axial bond force grows as the
//! bead moves outwards), and the bond's small net force across `a` is removed evenly over the
//! patch, so that each bead carries exactly `±F a`, as [`SmoothPatchPair`]'s patches do. As
//! `k → ∞` the patch lies on the sphere: a rigid contact whose shape is the bead's, with the
//! traction the rigid contact needs, not a uniform one. The bead is massless and its place is
//! found again at each step from the cell's surface (the trap sets the force, not the place).
//! The traction is explicit in the step, like every [`CellForce`], so `k` is bounded by the step:
//! a patch of size `ℓ` relaxes onto the bead at a rate of about `k ℓ/(4μ)`, which `Δt` must
//! resolve.

//!
//! **A bond to material points** ([`BondedPatchPair`]). The sphere's bond above holds the patch
//! on the bead's surface but lets the membrane slide over it, and the patch is chosen again at
//! every step. The bead of the experiment is glued to the membrane: the bonded membrane moves
//! as one rigid body. For a membrane whose grid points are material points (a capsule: no
//! re-parametrisation moves them), the patch's points and weights `w_j` are fixed at the first
//! step with their offsets `r_j` from the patch's weighted centroid, and each is tied by a
//! spring to its place on a rigid body of pose `(c, R)`:
//!
//! `t_j = k w_j (c + R (r_j − r̄) − x_j)`,
//!
//! `r̄` the offsets' centroid with the present area elements (zero until they change). `R` is
//! the rotation that best carries the offsets onto the patch's present shape (the polar
//! factor of `A = Σ w_j dA_j (x_j − x̄)(r_j − r̄)ᵀ`, Kabsch's fit), which makes the bond's
//! torque about the centroid `x̄` vanish; `c = x̄ + F a/(k Σ w_j dA_j)` makes its force `±F a`.
//! As `k → ∞` the patch keeps its shape and moves rigidly, carrying the trap's force: the
//! rigid contact of a bead bonded to the cell.

use std::sync::Mutex;

use super::cell_force::{unit, CellForce, CellView, SmoothPatchPair, VectorField};
use crate::linalg3::{dot3, matmul3, sub3, symmetric_eigen3};
use crate::vesicle::geometry::Geometry;

/// Two rigid beads bonded to the ends of a cell and pulled apart by `±F` (module docs).
#[derive(Clone, Debug)]
pub struct BeadPair {
    /// The bonded patches: the pulled cell, the axis, each patch's share of the area, the force
    /// `F` and the width of the patches' edges.
    pub patches: SmoothPatchPair,
    /// Radius `r` of each bead (positive).
    pub radius: f64,
    /// Bond stiffness `k`: traction per unit distance of a bonded point from the bead's
    /// surface (positive).
    pub stiffness: f64,
}

/// One bead: its centre and the traction of its bond at the grid points.
#[derive(Clone, Debug)]
pub struct Bead {
    /// Centre of the sphere.
    pub centre: [f64; 3],
    /// Traction at every grid point (zero off the patch).
    pub traction: Vec<[f64; 3]>,
}

impl BeadPair {
    /// Whether the parameters make sense (those of the patches, and a positive finite radius
    /// and stiffness).
    pub fn is_valid(&self) -> bool {
        self.patches.is_valid()
            && self.radius.is_finite()
            && self.radius > 0.0
            && self.stiffness.is_finite()
            && self.stiffness > 0.0
    }

    /// The `+` and `−` beads on the cell `g`: centres and bond tractions (each summing to
    /// `±F a` with the grid's weights).
    pub fn beads(&self, g: &Geometry) -> [Bead; 2] {
        let a = unit(self.patches.pair.axis);
        let f = self.patches.pair.force;
        let [wp, wm] = self.patches.weights(g);
        [(wp, 1.0), (wm, -1.0)].map(|(w, sign)| self.bead(g, a, &w, sign * f, sign))
    }

    /// The bead of weights `w` carrying `force` along `a`, on the `side` (±1) of the cell.
    fn bead(&self, g: &Geometry, a: [f64; 3], w: &[f64], force: f64, side: f64) -> Bead {
        let n = g.n_points();
        let (r, k) = (self.radius, self.stiffness);
        let patch: Vec<usize> = (0..n).filter(|&j| w[j] > 0.0).collect();
        let area: f64 = patch.iter().map(|&j| w[j] * g.da[j]).sum();
        let mut traction = vec![[0.0; 3]; n];
        if area <= 0.0 {
            return Bead {
                centre: [f64::NAN; 3],
                traction,
            };
        }
        // The patch's lateral centre, and the bond at a bead whose centre is `s` along `a`.
        let mut lateral = [0.0; 3];
        for &j in &patch {
            let x = g.x[j];
            let across = sub3(x, scale(a, dot3(x, a)));
            for c in 0..3 {
                lateral[c] += w[j] * g.da[j] * across[c] / area;
            }
        }
        let centre = |s: f64| add3(lateral, scale(a, s));
        let bond = |j: usize, c: [f64; 3]| -> [f64; 3] {
            let v = sub3(g.x[j], c);
            let d = dot3(v, v).sqrt();
            if d > 0.0 {
                scale(v, k * w[j] * (r - d) / d)
            } else {
                [0.0; 3]
            }
        };
        let axial = |s: f64| -> f64 {
            let c = centre(s);
            patch.iter().map(|&j| dot3(bond(j, c), a) * g.da[j]).sum()
        };
        // Bracket the bead's place, then bisect. The inner end starts with the bead's centre
        // on the patch's outermost point, where the bond pushes the patch inwards: along the
        // axis a second root lies inside the cell (the patch on the bead's far side), which an
        // inner end further in could take.
        let tip = patch
            .iter()
            .map(|&j| side * dot3(g.x[j], a))
            .fold(f64::MIN, f64::max);
        let (mut inner, mut outer) = (side * tip, side * (tip + r));
        let mut step = r;
        for _ in 0..60 {
            if (axial(outer) - force) * side >= 0.0 {
                break;
            }
            step *= 2.0;
            outer += side * step;
        }
        let mut step = r;
        for _ in 0..60 {
            if (axial(inner) - force) * side <= 0.0 {
                break;
            }
            step *= 2.0;
            inner -= side * step;
        }
        for _ in 0..200 {
            let mid = 0.5 * (inner + outer);
            if mid == inner || mid == outer {
                break;
            }
            if (axial(mid) - force) * side < 0.0 {
                inner = mid;
            } else {
                outer = mid;
            }
        }
        let c = centre(0.5 * (inner + outer));
        let mut net = [0.0; 3];
        for &j in &patch {
            traction[j] = bond(j, c);
            for (nc, tc) in net.iter_mut().zip(traction[j]) {
                *nc += tc * g.da[j];
            }
        }
        // What the bond carries beyond `force a`, taken off evenly over the patch's weights.
        let excess = sub3(net, scale(a, force));
        for &j in &patch {
            traction[j] = sub3(traction[j], scale(excess, w[j] / area));
        }
        Bead {
            centre: c,
            traction,
        }
    }
}

impl CellForce for BeadPair {
    fn name(&self) -> &str {
        "bead pair (optical tweezers, rigid contacts)"
    }

    fn add_traction(&self, cell: &CellView<'_>, out: &mut VectorField) {
        if cell.id != self.patches.pair.cell {
            return;
        }
        if !self.is_valid() {
            out.fill([f64::NAN; 3]);
            return;
        }
        for bead in self.beads(cell.geometry) {
            for (j, t) in bead.traction.iter().enumerate() {
                out.add(j, *t);
            }
        }
    }
}

/// Two patches bonded to rigid bodies that carry `±F` (module docs): the bond of a bead glued
/// to material points. The patches are those of `patches` at the first step, kept on the same
/// grid points after it, so the membrane's grid must follow its material points (a capsule).
#[derive(Debug)]
pub struct BondedPatchPair {
    /// The patches at the first step: the pulled cell, the axis, each patch's share of the
    /// area, the force and the width of the edges.
    pub patches: SmoothPatchPair,
    /// Bond stiffness `k` (positive): traction per unit distance of a bonded point from its
    /// place on the rigid body.
    pub stiffness: f64,
    /// The bonded grid's size and, per patch, the bonded points `(index, weight, offset from
    /// the centroid)` (set at the first step).
    #[allow(clippy::type_complexity)]
    bonds: Mutex<Option<(usize, [Vec<(usize, f64, [f64; 3])>; 2])>>,
}

impl BondedPatchPair {
    /// The pair bonded at its first step.
    pub fn new(patches: SmoothPatchPair, stiffness: f64) -> Self {
        BondedPatchPair {
            patches,
            stiffness,
            bonds: Mutex::new(None),
        }
    }

    /// Whether the parameters make sense.
    pub fn is_valid(&self) -> bool {
        self.patches.is_valid() && self.stiffness.is_finite() && self.stiffness > 0.0
    }

    /// The bond's tractions at the grid points of `g` (bonding the patches of `g` if this is
    /// the first call) and, per patch, the rigid body's place of each bonded point
    /// `c + R (r_j − r̄)`; `None` when `g` has another number of points than the bonded grid.
    #[allow(clippy::type_complexity)]
    pub fn bond(&self, g: &Geometry) -> Option<(Vec<[f64; 3]>, [Vec<[f64; 3]>; 2])> {
        let n = g.n_points();
        let a = unit(self.patches.pair.axis);
        let mut guard = self.bonds.lock().unwrap_or_else(|e| e.into_inner());
        let (bonded_n, bonds) = guard.get_or_insert_with(|| {
            let bonds = self.patches.weights(g).map(|w| {
                let patch: Vec<usize> = (0..n).filter(|&j| w[j] > 0.0).collect();
                let centre = weighted_centroid(g, patch.iter().map(|&j| (j, w[j])));
                patch
                    .into_iter()
                    .map(|j| (j, w[j], sub3(g.x[j], centre)))
                    .collect()
            });
            (n, bonds)
        });
        if *bonded_n != n {
            return None;
        }
        let mut traction = vec![[0.0; 3]; n];
        let k = self.stiffness;
        let places = [0, 1].map(|side| {
            let bond = &bonds[side];
            let force = if side == 0 { 1.0 } else { -1.0 } * self.patches.pair.force;
            let area: f64 = bond.iter().map(|&(j, w, _)| w * g.da[j]).sum();
            let centroid = weighted_centroid(g, bond.iter().map(|&(j, w, _)| (j, w)));
            // The offsets' own centroid with today's areas (zero until the membrane's area
            // elements change).
            let mut r_bar = [0.0; 3];
            for &(j, w, r) in bond {
                r_bar = add3(r_bar, scale(r, w * g.da[j] / area));
            }
            // A = Σ w dA (x − x̄)(r − r̄)ᵀ; R = A (AᵀA)^(−1/2).
            let mut m = [[0.0; 3]; 3];
            for &(j, w, r) in bond {
                let r = sub3(r, r_bar);
                let d = sub3(g.x[j], centroid);
                for (p, row) in m.iter_mut().enumerate() {
                    for (q, v) in row.iter_mut().enumerate() {
                        *v += w * g.da[j] * d[p] * r[q];
                    }
                }
            }
            let rotation = polar_factor(m);
            let c = add3(centroid, scale(a, force / (k * area)));
            bond.iter()
                .map(|&(j, w, r)| {
                    let place = add3(c, matvec(rotation, sub3(r, r_bar)));
                    traction[j] = add3(traction[j], scale(sub3(place, g.x[j]), k * w));
                    place
                })
                .collect()
        });
        Some((traction, places))
    }
}

impl CellForce for BondedPatchPair {
    fn name(&self) -> &str {
        "bonded patch pair (optical tweezers, beads glued to the membrane)"
    }

    fn add_traction(&self, cell: &CellView<'_>, out: &mut VectorField) {
        if cell.id != self.patches.pair.cell {
            return;
        }
        // Invalid parameters bond nothing.
        match self.is_valid().then(|| self.bond(cell.geometry)).flatten() {
            Some((traction, _)) => {
                for (j, t) in traction.iter().enumerate() {
                    out.add(j, *t);
                }
            }
            None => out.fill([f64::NAN; 3]),
        }
    }
}

/// `Σ w_j dA_j x_j / Σ w_j dA_j` over the `(j, w_j)`.
fn weighted_centroid(g: &Geometry, points: impl Iterator<Item = (usize, f64)>) -> [f64; 3] {
    let (mut sum, mut total) = ([0.0; 3], 0.0);
    for (j, w) in points {
        sum = add3(sum, scale(g.x[j], w * g.da[j]));
        total += w * g.da[j];
    }
    scale(sum, 1.0 / total)
}

/// The rotation nearest to `A` (Kabsch): its polar factor `R = A (AᵀA)^(−1/2)` when
/// `det A > 0`, and otherwise `A Σ ± λ_i^(−1/2) v_i v_iᵀ` with the sign of the smallest
/// singular direction flipped (a proper rotation, not a reflection), from the
/// eigen-decomposition `AᵀA = Σ λ_i v_i v_iᵀ`.
fn polar_factor(a: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let at = [0, 1, 2].map(|i| [0, 1, 2].map(|j| a[j][i]));
    let (vals, vecs) = symmetric_eigen3(matmul3(at, a));
    let det = dot3(a[0], crate::linalg3::cross3(a[1], a[2]));
    let mut inv_sqrt = [[0.0; 3]; 3];
    for (i, &l) in vals.iter().enumerate() {
        // The eigenvalues ascend: the first is the smallest singular direction.
        let flip = if i == 0 && det < 0.0 { -1.0 } else { 1.0 };
        let s = flip / l.max(f64::MIN_POSITIVE).sqrt();
        for (p, row) in inv_sqrt.iter_mut().enumerate() {
            for (q, v) in row.iter_mut().enumerate() {
                *v += s * vecs[p][i] * vecs[q][i];
            }
        }
    }
    matmul3(a, inv_sqrt)
}

fn matvec(m: [[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    m.map(|row| dot3(row, v))
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    a.map(|v| v * s)
}

fn add3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::timestep::cell_force::PatchPair;
    use crate::vesicle::shapes;

    use crate::vesicle::geometry::SurfaceCalculus;

    fn rbc_geometry(p: usize) -> Geometry {
        let rbc = shapes::rbc(p).unwrap();
        SurfaceCalculus::new(p)
            .unwrap()
            .geometry(rbc.coefs())
            .unwrap()
    }

    fn pair(force: f64, stiffness: f64) -> BeadPair {
        BeadPair {
            patches: SmoothPatchPair {
                pair: PatchPair {
                    cell: 0,
                    axis: [1.0, 0.0, 0.0],
                    fraction: 0.025,
                    force,
                },
                width: 0.1,
            },
            radius: 0.73,
            stiffness,
        }
    }

    /// Each bead carries exactly `±F a` on the grid, the beads sit outside the cell's ends on
    /// the axis, and the bond pulls the patch outwards (towards its bead) on average.
    #[test]
    fn each_bead_carries_its_force_and_no_more() {
        let g = rbc_geometry(12);
        let (f, a) = (4.9, [1.0, 0.0, 0.0]);
        for k in [50.0, 500.0] {
            let beads = pair(f, k).beads(&g);
            for (bead, sign) in beads.iter().zip([1.0, -1.0]) {
                let mut net = [0.0; 3];
                for (t, da) in bead.traction.iter().zip(&g.da) {
                    for c in 0..3 {
                        net[c] += t[c] * da;
                    }
                }
                let want = scale(a, sign * f);
                let err = dot3(sub3(net, want), sub3(net, want)).sqrt();
                assert!(err < 1e-12 * f, "k = {k}: {net:?} against {want:?}");
                // The bond's own force at the bead's place, before the lateral excess is taken
                // off: the bisection found the place where it carries ±F along a (and nothing
                // across it, the RBC being symmetric about the axis).
                let w = &pair(f, k).patches.weights(&g)[if sign > 0.0 { 0 } else { 1 }];
                let mut raw = [0.0; 3];
                for j in (0..g.n_points()).filter(|&j| w[j] > 0.0) {
                    let v = sub3(g.x[j], bead.centre);
                    let d = dot3(v, v).sqrt();
                    raw = add3(raw, scale(v, k * w[j] * (0.73 - d) / d * g.da[j]));
                }
                let err = dot3(sub3(raw, want), sub3(raw, want)).sqrt();
                assert!(
                    err < 1e-9 * f,
                    "k = {k}: the bond carries {raw:?}, not {want:?}"
                );
                // The RBC's rim reaches x = ±1.386... (its bounding radius); the bead's centre
                // lies beyond it by about its radius, on the axis by symmetry.
                let c = bead.centre;
                assert!(
                    sign * c[0] > 1.3 && c[1].abs() < 1e-10 && c[2].abs() < 1e-10,
                    "{c:?}"
                );
            }
        }
    }

    /// The bond's traction at a point is the pull of a spring to the sphere: `−∂E/∂x` of the
    /// point's bond energy `½ k w_j (d_j − r)²` with the bead held still (central differences;
    /// the even removal of the lateral excess is round-off here, the RBC being symmetric about
    /// the pull axis).
    #[test]
    fn the_bond_pulls_each_point_to_the_sphere() {
        let g = rbc_geometry(12);
        let k = 300.0;
        let bp = pair(4.9, k);
        let [bead, _] = bp.beads(&g);
        let [w, _] = bp.patches.weights(&g);
        let energy = |j: usize, x: [f64; 3]| {
            let d = dot3(sub3(x, bead.centre), sub3(x, bead.centre)).sqrt();
            0.5 * k * w[j] * (d - bp.radius).powi(2)
        };
        let h = 1e-6;
        let mut checked = 0;
        for j in (0..g.n_points()).filter(|&j| w[j] > 0.0) {
            for c in 0..3 {
                let (mut xp, mut xm) = (g.x[j], g.x[j]);
                xp[c] += h;
                xm[c] -= h;
                let fd = -(energy(j, xp) - energy(j, xm)) / (2.0 * h);
                let t = bead.traction[j][c];
                assert!(
                    (t - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                    "point {j}, component {c}: {t} against {fd}"
                );
            }
            checked += 1;
        }
        assert!(checked > 4, "{checked} bonded points");
    }

    /// The bonded pair: each patch carries exactly `±F a` and no torque about its centroid;
    /// on a rigidly moved (turned and shifted) cell the places are the bonded points moved
    /// with it, so the traction is the uniform pull `F a / Σ w dA` times the weight; and a
    /// grid of another size is refused.
    #[test]
    fn a_bonded_patch_moves_as_one_body() {
        let p = 12;
        let g = rbc_geometry(p);
        let (f, k) = (4.9, 200.0);
        let bp = BondedPatchPair::new(pair(f, k).patches, k);
        let (t0, _) = bp.bond(&g).unwrap();
        // Turn the cell by 0.3 rad about (1, 2, 2)/3 and shift it: the bonded points' places
        // are where the move takes them (up to the pull's offset along a).
        let rot = crate::linalg3::rotation_from_vector([0.1, 0.2, 0.2]);
        let rbc = shapes::rbc(p).unwrap();
        let mut moved = rbc.clone();
        moved.rotate(rot).unwrap();
        moved.translate([0.3, -0.2, 0.5]);
        let gm = SurfaceCalculus::new(p)
            .unwrap()
            .geometry(moved.coefs())
            .unwrap();
        let (tm, _) = bp.bond(&gm).unwrap();
        let [w_plus, w_minus] = bp.patches.weights(&g);
        for (side, w) in [(1.0, &w_plus), (-1.0, &w_minus)] {
            let area: f64 = (0..g.n_points()).map(|j| w[j] * g.da[j]).sum();
            for j in (0..g.n_points()).filter(|&j| w[j] > 0.0) {
                // Unmoved: exactly the uniform pull along x.
                let want = [side * f * w[j] / area, 0.0, 0.0];
                let err = dot3(sub3(t0[j], want), sub3(t0[j], want)).sqrt();
                assert!(
                    err < 1e-10 * f / area,
                    "point {j}: {:?} against {want:?}",
                    t0[j]
                );
                // Moved: the same pull, along the unturned axis (the bead is pulled along a).
                let err = dot3(sub3(tm[j], want), sub3(tm[j], want)).sqrt();
                assert!(
                    err < 1e-8 * f / area,
                    "moved, point {j}: {:?} against {want:?}",
                    tm[j]
                );
            }
        }
        // A deformed cell: net force ±F a and no torque about each patch's centroid.
        let mut bent = rbc.clone();
        let nc = bent.coefs().len() / 3;
        bent.coefs_mut()[3] += 0.05;
        bent.coefs_mut()[nc + 5] -= 0.04;
        let gb = SurfaceCalculus::new(p)
            .unwrap()
            .geometry(bent.coefs())
            .unwrap();
        let (tb, _) = bp.bond(&gb).unwrap();
        for (side, w) in [(1.0, &w_plus), (-1.0, &w_minus)] {
            let patch: Vec<usize> = (0..gb.n_points()).filter(|&j| w[j] > 0.0).collect();
            let centre = weighted_centroid(&gb, patch.iter().map(|&j| (j, w[j])));
            let (mut net, mut torque) = ([0.0; 3], [0.0; 3]);
            for &j in &patch {
                net = add3(net, scale(tb[j], gb.da[j]));
                let arm = sub3(gb.x[j], centre);
                torque = add3(torque, scale(crate::linalg3::cross3(arm, tb[j]), gb.da[j]));
            }
            let err = dot3(
                sub3(net, [side * f, 0.0, 0.0]),
                sub3(net, [side * f, 0.0, 0.0]),
            );
            assert!(err.sqrt() < 1e-10 * f, "{net:?}");
            assert!(dot3(torque, torque).sqrt() < 1e-10 * f, "torque {torque:?}");
        }
        assert!(bp.bond(&rbc_geometry(p + 2)).is_none());
    }

    #[test]
    fn invalid_beads_write_nan() {
        let g = rbc_geometry(6);
        let mut bp = pair(1.0, 100.0);
        bp.radius = 0.0;
        let coefs = shapes::rbc(6).unwrap().coefs().to_vec();
        let view = CellView {
            id: 0,
            time: 0.0,
            coefs: &coefs,
            geometry: &g,
        };
        let mut out = VectorField::zeros(g.n_points());
        bp.add_traction(&view, &mut out);
        assert!(out.point(0)[0].is_nan());
    }
}
