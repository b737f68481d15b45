//! Forces a caller adds to cells, per cell and per step: optical tweezers, confining
//! potentials, walls or adhesion of a study's own.
//!
//! A [`CellForce`] sees each cell at the start of a step, `Xⁿ` ([`CellView`]: its global index,
//! the time, its coefficients and its [`Geometry`] on the order-`p` grid: points, normals,
//! curvatures, quadrature weights `dA`), and adds a traction `t` (force per unit area of
//! membrane, the force the membrane exerts on the fluid, the sign convention of the body force)
//! at the grid points, one 3-vector per point ([`VectorField`], the layout of `geometry.x` and
//! `geometry.normal`). The step applies it explicitly, like the contact repulsion: through the
//! cell's own single layer `S[t]` in its step and through the coupling, so that the other cells
//! feel the flow it drives. Like the contact repulsion, the traction is taken at `Xⁿ` and not
//! extrapolated: with BDF2 a user force is first order in time. A point force `F` on a patch `P` is the traction `F / |P|` on the
//! patch (`∫_P t dA = F` with the grid's weights); a potential `U(x)` per unit area gives
//! `t = −∇U(X)`.
//!
//! [`ForceFn`] wraps a closure; [`PatchPair`] is the optical-tweezers load of cell-stretching
//! experiments (Mills et al., Mech. Chem. Biosyst. 1, 2004; Fedosov et al., Biophys. J. 98,
//! 2010): `±F` along an axis on the two end patches of a cell, each the points whose position
//! along the axis lies in the outer `fraction` of the cell's extent.

use crate::vesicle::dot;
use crate::vesicle::geometry::Geometry;
pub use crate::vesicle::vector_field::VectorField;

/// One cell as a [`CellForce`] sees it, at the start of a step.
#[derive(Clone, Copy, Debug)]
pub struct CellView<'a> {
    /// Global index of the cell (the order of the scene's cells).
    pub id: usize,
    /// Time at the start of the step.
    pub time: f64,
    /// Order-`p` SH coefficients `Xⁿ` (x, y, z).
    pub coefs: &'a [f64],
    /// Geometry of `Xⁿ` on the order-`p` grid (`geometry.x`, `geometry.normal`, `geometry.da`).
    pub geometry: &'a Geometry,
}

/// A force a caller adds to cells, evaluated once per cell and step.
pub trait CellForce: Send + Sync {
    /// A name for logs and the effects list.
    fn name(&self) -> &str;

    /// Add the traction (force per unit area) at the cell's grid points to `out`: at point `k`
    /// (`geometry.x[k]`), `out.add(k, t_k)` (`n = geometry.n_points()` points, all zero when
    /// the first force is asked).
    fn add_traction(&self, cell: &CellView<'_>, out: &mut VectorField);
}

/// A [`CellForce`] from a closure `f(cell, out)` with a name.
pub struct ForceFn<F> {
    name: String,
    f: F,
}

impl<F> ForceFn<F>
where
    F: Fn(&CellView<'_>, &mut VectorField) + Send + Sync,
{
    /// The closure `f` under `name`.
    pub fn new(name: &str, f: F) -> Self {
        ForceFn {
            name: name.to_string(),
            f,
        }
    }
}

impl<F> CellForce for ForceFn<F>
where
    F: Fn(&CellView<'_>, &mut VectorField) + Send + Sync,
{
    fn name(&self) -> &str {
        &self.name
    }

    fn add_traction(&self, cell: &CellView<'_>, out: &mut VectorField) {
        (self.f)(cell, out)
    }
}

/// Opposite forces `+F a` and `−F a` (unit axis `a`) on the two end patches of one cell, as
/// optical tweezers apply them through two beads: the `+` patch holds the grid points of
/// largest `x·a` that together carry a share `fraction` of the cell's area (`Σ dA`), the `−`
/// patch likewise those of smallest `x·a` (Mills et al. 2004: a bead contact of ~2 µm diameter
/// on a cell of 135 µm², a share of about 2–3 %). Each patch carries the uniform traction
/// `±F a / |P|`, so that `∫_P t dA = ±F a` exactly on the grid and the net force is zero.
#[derive(Clone, Debug)]
pub struct PatchPair {
    /// Global index of the pulled cell.
    pub cell: usize,
    /// Direction of the pull (normalised when used).
    pub axis: [f64; 3],
    /// Share of the cell's area in each patch, in `(0, 0.5]` (the last points at the same
    /// position along the axis join too).
    pub fraction: f64,
    /// Magnitude `F` of the force on each patch.
    pub force: f64,
}

impl PatchPair {
    /// Whether the parameters make sense: `fraction` in `(0, 0.5]`, a finite non-zero axis,
    /// a finite force. [`CellForce::add_traction`] of an invalid pair writes NaN, which the
    /// step reports as a non-finite user traction on the cell.
    pub fn is_valid(&self) -> bool {
        self.fraction > 0.0
            && self.fraction <= 0.5
            && self.axis.iter().all(|v| v.is_finite())
            && dot(self.axis, self.axis) > 0.0
            && self.force.is_finite()
    }

    /// Per grid point: `+1` on the `+` patch, `−1` on the `−` patch, `0` elsewhere. Points at
    /// the same position along the axis (to 1e-12 of the extent) join a patch together, so
    /// that a surface and grid symmetric under `x·a → −x·a` get mirror-image patches.
    pub fn patches(&self, g: &Geometry) -> Vec<i8> {
        let a = unit(self.axis);
        let s: Vec<f64> = g.x.iter().map(|x| dot(*x, a)).collect();
        let mut order: Vec<usize> = (0..s.len()).collect();
        order.sort_by(|&i, &j| s[i].total_cmp(&s[j]));
        let (lo, hi) = match (order.first(), order.last()) {
            (Some(&i), Some(&j)) => (s[i], s[j]),
            _ => return Vec::new(),
        };
        let tie = 1e-12 * (hi - lo);
        let share = self.fraction.clamp(0.0, 0.5) * g.area();
        let mut side = vec![0i8; s.len()];
        for (sign, ends) in [
            (-1i8, &mut order.iter() as &mut dyn Iterator<Item = &usize>),
            (1, &mut order.iter().rev()),
        ] {
            let mut taken = 0.0;
            let mut last = f64::NAN;
            for &j in ends {
                let full = taken >= share && (s[j] - last).abs() > tie;
                if full || side[j] != 0 {
                    break;
                }
                side[j] = sign;
                taken += g.da[j];
                last = s[j];
            }
        }
        side
    }
}

impl CellForce for PatchPair {
    fn name(&self) -> &str {
        "patch pair (optical tweezers)"
    }

    fn add_traction(&self, cell: &CellView<'_>, out: &mut VectorField) {
        if cell.id != self.cell {
            return;
        }
        if !self.is_valid() {
            out.fill([f64::NAN; 3]);
            return;
        }
        let g = cell.geometry;
        let a = unit(self.axis);
        let side = self.patches(g);
        for sign in [1i8, -1] {
            let weight = |j: usize| if side[j] == sign { 1.0 } else { 0.0 };
            spread(out, g, a, f64::from(sign) * self.force, weight);
        }
    }
}

/// [`PatchPair`] with a smooth edge: the load `±F a` spread with the weight
/// `w = h((x·a − s_±)/(W L))` (`h` the C¹ ramp `3u² − 2u³` from 0 at `u = −½` to 1 at `u = ½`,
/// `L` the cell's extent along `a`, `W` = [`width`](Self::width)), the centre `s_±` of each
/// edge set by bisection so that `Σ w dA = fraction · A`; the traction is `±F a w / Σ w dA`.
/// The weight is continuous in the positions, so the load does not jump when grid points cross
/// the edge (the reparametrisation moves them along the surface every step), which a hard
/// patch does; `W → 0` is the hard patch.
#[derive(Clone, Debug)]
pub struct SmoothPatchPair {
    /// The pulled cell, axis, area share of each patch and force, as for [`PatchPair`].
    pub pair: PatchPair,
    /// Width of the edge as a share of the cell's extent along the axis (positive).
    pub width: f64,
}

/// The C¹ ramp: 0 below `−½`, 1 above `½`, `3t² − 2t³` with `t = u + ½` between.
fn ramp(u: f64) -> f64 {
    let t = (u + 0.5).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl SmoothPatchPair {
    /// Whether the parameters make sense: those of [`PatchPair::is_valid`] and a positive,
    /// finite edge width.
    pub fn is_valid(&self) -> bool {
        self.pair.is_valid() && self.width.is_finite() && self.width > 0.0
    }

    /// Per grid point, the weights of the `+` and `−` patches (each in `[0, 1]`).
    pub fn weights(&self, g: &Geometry) -> [Vec<f64>; 2] {
        let a = unit(self.pair.axis);
        let s: Vec<f64> = g.x.iter().map(|x| dot(*x, a)).collect();
        let (lo, hi) = s
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        let w = self.width * (hi - lo);
        let share = self.pair.fraction.clamp(0.0, 0.5) * g.area();
        [1.0, -1.0].map(|sign: f64| {
            // Σ h(sign (s − c)/w) dA falls as c moves inwards → outwards: bisection on c.
            let load = |c: f64| -> f64 {
                s.iter()
                    .zip(&g.da)
                    .map(|(&sj, &da)| ramp(sign * (sj - c) / w) * da)
                    .sum()
            };
            let (mut inner, mut outer) = if sign > 0.0 {
                (lo, hi + w)
            } else {
                (hi, lo - w)
            };
            for _ in 0..100 {
                let mid = 0.5 * (inner + outer);
                if load(mid) > share {
                    inner = mid;
                } else {
                    outer = mid;
                }
            }
            let c = 0.5 * (inner + outer);
            s.iter().map(|&sj| ramp(sign * (sj - c) / w)).collect()
        })
    }
}

impl CellForce for SmoothPatchPair {
    fn name(&self) -> &str {
        "smooth patch pair (optical tweezers)"
    }

    fn add_traction(&self, cell: &CellView<'_>, out: &mut VectorField) {
        if cell.id != self.pair.cell {
            return;
        }
        if !self.is_valid() {
            out.fill([f64::NAN; 3]);
            return;
        }
        let g = cell.geometry;
        let a = unit(self.pair.axis);
        for (w, sign) in self.weights(g).iter().zip([1.0, -1.0]) {
            spread(out, g, a, sign * self.pair.force, |j| w[j]);
        }
    }
}

/// `out += (F / Σ w dA) w a`: the force `F a` spread over the points of weight `w` (nothing
/// where the weights carry no area).
fn spread(out: &mut VectorField, g: &Geometry, a: [f64; 3], force: f64, w: impl Fn(usize) -> f64) {
    let n = g.n_points();
    let area: f64 = (0..n).map(|j| w(j) * g.da[j]).sum();
    if area <= 0.0 {
        return;
    }
    let t = force / area;
    for j in 0..n {
        let wj = w(j);
        if wj != 0.0 {
            out.add(j, a.map(|ac| t * wj * ac));
        }
    }
}

/// `a` normalised (the x axis for a zero vector).
pub(super) fn unit(a: [f64; 3]) -> [f64; 3] {
    let r = dot(a, a).sqrt();
    if r > 0.0 {
        [a[0] / r, a[1] / r, a[2] / r]
    } else {
        [1.0, 0.0, 0.0]
    }
}
