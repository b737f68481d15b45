//! A fixed curved wall as the contact projection sees it: a rigid body (the allowed side is
//! outside) or a container of [`crate::wall`] (the allowed side is inside), measured by Newton's
//! closest point ([`SurfaceDistance`]).
//!
//! **Which samples need no Newton solve.** A cell's sample `x` whose gap is at least the
//! contact range `r` gives no constraint, and Newton's closest point on a large wall costs
//! about 0.1 ms a sample (an order-40 tube), while most samples of a cell in a tube are far
//! from its wall. [`FixedSurface::clear_samples`] proves such samples clear without a solve:
//!
//! * **Distance.** Let `s` bound the distance of any surface point from its nearest sample of
//!   the wall's order-`2p` grid (the largest diagonal of a grid cell, or the diameter of a pole's
//!   first ring). Then `dist(x, Γ) ≥ ℓ(x) = min_j |x − y_j| − s`: the ball of radius `ℓ(x)`
//!   about `x` holds no point of the wall.
//! * **Side.** The cell's centre `c` takes one Newton solve: its signed gap says its side. A
//!   sample `x` is on the same side when the segment from `c` to `x` lies in the union of the
//!   two wall-free balls, `max(ℓ(c), 0) + ℓ(x) ≥ |x − c|`, or when a neighbour `x'` on the
//!   cell's grid, already shown on that side, has `ℓ(x) + ℓ(x') ≥ |x − x'|` (the side spreads
//!   over the grid).
//!
//! A sample with `ℓ(x) > r` on the allowed side is clear: its Newton gap, the distance to a
//! closest point and never below the true one, would exceed `r` too, so skipping it changes no
//! constraint. Every other sample is measured by Newton as before. Only the wall's samples
//! within `reach + R` of the centre are searched (`R` the search radius below), so `ℓ(x)` is
//! taken no larger than `R − s`.
//!
//! The reference is Newton at every sample (the tests): no clear sample has a gap below `r`.

use std::collections::VecDeque;

use crate::linalg3::{dist3 as dist, dist3_squared as dist2};
use crate::sph_harmonics::ShTransform;
use crate::vesicle::smooth_layer::node_slack;
use crate::vesicle::surface_distance::{Closest, DistanceScratch, SurfaceDistance};
use crate::vesicle::VesicleError;

/// A fixed curved wall (a rigid body or a container of [`crate::wall`]): the allowed side is
/// outside a body and inside a container. A cell's order-`2p` samples are measured against it
/// by Newton's closest point where they are not proven clear of it
/// ([`FixedSurface::clear_samples`]); only the cell moves.
pub struct FixedSurface {
    surface: SurfaceDistance,
    p: usize,
    container: bool,
    /// The smallest distance of the surface from its centre, less a sample spacing (a
    /// container's samples closer to its centre than this less the range need no test).
    r_min: f64,
    /// The largest distance of a surface point from its nearest sample (module docs).
    slack: f64,
}

impl FixedSurface {
    /// The surface of order `p` with coefficients `coefs`; `container`: the allowed side is
    /// inside.
    pub fn new(p: usize, coefs: &[f64], container: bool) -> Result<Self, VesicleError> {
        let sht = ShTransform::new(2 * p).map_err(VesicleError::Sph)?;
        let surface = SurfaceDistance::new(p, coefs, &sht)?;
        let c = surface.centre();
        let lo = surface
            .samples()
            .iter()
            .map(|&y| dist(y, c))
            .fold(f64::INFINITY, f64::min);
        let r_min = lo - std::f64::consts::PI * surface.reach() / (2 * p) as f64;
        let slack = node_slack(surface.samples(), 2 * p);
        Ok(FixedSurface {
            surface,
            p,
            container,
            r_min,
            slack,
        })
    }

    /// The order of the surface (the order of a [`DistanceScratch`] for it).
    pub fn order(&self) -> usize {
        self.p
    }

    /// The surface with its samples.
    pub(super) fn surface(&self) -> &SurfaceDistance {
        &self.surface
    }

    /// Whether the allowed side is inside.
    pub(super) fn is_container(&self) -> bool {
        self.container
    }

    /// The smallest distance of the surface from its centre, less a sample spacing.
    pub(super) fn r_min(&self) -> f64 {
        self.r_min
    }

    /// The gap of a point whose closest point on the surface is `cl`, positive on the allowed
    /// side, and the normal into that side.
    pub(super) fn gap_and_normal(&self, cl: &Closest) -> (f64, [f64; 3]) {
        if self.container {
            (-cl.distance, cl.normal.map(|v| -v))
        } else {
            (cl.distance, cl.normal)
        }
    }

    /// The distance of `x` from the surface, positive on the allowed side (`scratch` of
    /// [`Self::order`]).
    pub fn clearance(&self, scratch: &mut DistanceScratch, x: [f64; 3]) -> f64 {
        self.gap_and_normal(&self.surface.closest(scratch, x)).0
    }

    /// For each of `body`'s samples, whether it is proven more than `range` from this surface
    /// on the allowed side (module docs), so that its gap need not be measured. One Newton
    /// solve, at the body's centre (`scratch` of [`Self::order`]); all `false` when the centre
    /// is not on the allowed side.
    pub fn clear_samples(
        &self,
        body: &SurfaceDistance,
        scratch: &mut DistanceScratch,
        range: f64,
    ) -> Vec<bool> {
        let xs = body.samples();
        let mut clear = vec![false; xs.len()];
        let c = body.centre();
        if self.clearance(scratch, c) <= 0.0 {
            return clear;
        }
        // The wall's samples that can matter: within the body's reach plus the search radius
        // of its centre. Beyond the search radius a sample's bound is taken as that radius.
        let search = range + 2.0 * self.slack + body.reach();
        let limit2 = (body.reach() + search).powi(2);
        let near: Vec<[f64; 3]> = self
            .surface
            .samples()
            .iter()
            .copied()
            .filter(|&y| dist2(y, c) <= limit2)
            .collect();
        let bound = |x: [f64; 3]| {
            let d2 = near
                .iter()
                .fold(search * search, |m, &y| m.min(dist2(x, y)));
            d2.sqrt() - self.slack
        };
        let lc = bound(c).max(0.0);
        let lb: Vec<f64> = xs.iter().map(|&x| bound(x)).collect();
        let nl = body.n_lon();
        let n_lat = xs.len() / nl;
        let mut queue = VecDeque::new();
        for (j, &x) in xs.iter().enumerate() {
            if lb[j] > range && lc + lb[j] >= dist(x, c) {
                clear[j] = true;
                queue.push_back(j);
            }
        }
        // The allowed side spreads over the body's grid between overlapping wall-free balls.
        while let Some(j) = queue.pop_front() {
            let (i, k) = (j / nl, j % nl);
            let mut next = [None; 4];
            next[0] = Some(i * nl + (k + 1) % nl);
            next[1] = Some(i * nl + (k + nl - 1) % nl);
            next[2] = (i > 0).then(|| (i - 1) * nl + k);
            next[3] = (i + 1 < n_lat).then(|| (i + 1) * nl + k);
            for m in next.into_iter().flatten() {
                if !clear[m] && lb[m] > range && lb[j] + lb[m] >= dist(xs[j], xs[m]) {
                    clear[m] = true;
                    queue.push_back(m);
                }
            }
        }
        clear
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::shapes;
    use crate::wall::tube_surface;

    /// The naive reference: Newton at every sample. No sample called clear has a gap below the
    /// range (or lies on the wrong side), and in a tube most samples of a cell are clear.
    fn check_clear(f: &FixedSurface, body: &SurfaceDistance, range: f64) -> (usize, usize) {
        let mut scratch = DistanceScratch::new(f.order());
        let clear = f.clear_samples(body, &mut scratch, range);
        let mut n_clear = 0;
        for (j, &x) in body.samples().iter().enumerate() {
            if clear[j] {
                let g = f.clearance(&mut scratch, x);
                assert!(
                    g > range,
                    "sample {j} called clear at gap {g} (range {range})"
                );
                n_clear += 1;
            }
        }
        (n_clear, clear.len())
    }

    fn rbc_at(p: usize, c: [f64; 3], tilt: f64) -> SurfaceDistance {
        let mut s = shapes::rbc(p).unwrap();
        let (sn, cs) = tilt.sin_cos();
        s.rotate([[cs, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, cs]])
            .unwrap();
        s.translate(c);
        let sht = ShTransform::new(2 * p).unwrap();
        SurfaceDistance::new(p, s.coefs(), &sht).unwrap()
    }

    #[test]
    fn samples_proven_clear_of_a_tube_are_clear_by_newton() {
        let (radius, length, q, p) = (2.5, 10.0, 24, 8);
        let tube = tube_surface(q, radius, length).unwrap();
        let f = FixedSurface::new(q, tube.coefs(), true).unwrap();
        let range = 0.15;
        // On the axis, off it, against the wall (about 0.1 from it), tilted, near an end.
        let places = [
            ([0.0, 0.0, 0.0], 0.0),
            ([1.0, 0.4, 0.0], 0.7),
            ([0.0, 0.0, radius - 1.45], std::f64::consts::FRAC_PI_2),
            ([0.0, 1.2, 0.0], 0.3),
            ([4.0, 0.0, 0.5], 1.0),
        ];
        let mut total = (0, 0);
        for (c, tilt) in places {
            let body = rbc_at(p, c, tilt);
            let (n, all) = check_clear(&f, &body, range);
            total = (total.0 + n, total.1 + all);
        }
        // Most samples need no Newton solve.
        eprintln!("{} of {} samples clear", total.0, total.1);
        assert!(
            4 * total.0 > 3 * total.1,
            "{} of {} samples clear",
            total.0,
            total.1
        );
    }

    #[test]
    fn a_body_outside_a_rigid_sphere_and_a_cell_outside_a_container_are_handled() {
        let p = 8;
        let q = 16;
        let sphere = shapes::sphere(q, 1.0).unwrap();
        let f = FixedSurface::new(q, sphere.coefs(), false).unwrap();
        // A cell whose dimple is about 0.1 above the rigid sphere (the dimple is 0.144 from
        // the cell's centre): some samples clear, none wrongly.
        let body = rbc_at(p, [0.0, 0.0, 1.25], 0.0);
        let (n, all) = check_clear(&f, &body, 0.15);
        assert!(n > 0 && n < all, "{n} of {all}");
        // A cell whose centre is outside a container: nothing is called clear.
        let shell = shapes::sphere(q, 3.0).unwrap();
        let f = FixedSurface::new(q, shell.coefs(), true).unwrap();
        let body = rbc_at(p, [0.0, 0.0, 4.0], 0.0);
        let mut scratch = DistanceScratch::new(q);
        assert!(f
            .clear_samples(&body, &mut scratch, 0.15)
            .iter()
            .all(|&c| !c));
    }
}
