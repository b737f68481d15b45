//! The signed distance from a point to a cell's surface, with the closest surface point and the
//! outward normal there: what contacts and the overlap test of a scene measure gaps with.
//!
//! The surface `X(θ, φ) = Σ c_nm Y_n^m(θ, φ)` is sampled on the grid of an order `q ≥ p`
//! (spacing about `2π R_max / (2q)`); the nearest sample starts Newton's method on
//! `½ |X(θ, φ) − x|²` (the crate's closest-point solve), which converges to the closest point `y` of the
//! continuous surface. The distance is `|x − y|`, negative when `x − y` points against the
//! outward normal `X_θ × X_φ` (the point is inside). A point farther than `far` from every sample
//! (with the grid spacing added) returns its distance to the nearest sample, an upper bound, and
//! no Newton solve: what only asks "is it within `far`?" pays for the samples alone.
//!
//! The reference is the brute-force minimum over a fine grid (the tests): the Newton distance is
//! never above it and agrees with it to the fine grid's resolution, and for a sphere it is
//! `|x − c| − r` to round-off.

use super::point::{closest_point, PointEval};
use super::shapes::Surface;
use super::{dot, VesicleError};
use crate::linalg3::{dist3 as dist, dist3_squared as dist2};
use crate::sph_harmonics::{CoefLayout, Grid, ShTransform};

/// The closest point of a surface to a target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Closest {
    /// Signed distance: positive outside the surface, negative inside.
    pub distance: f64,
    /// The closest surface point.
    pub point: [f64; 3],
    /// The unit outward normal at [`Closest::point`].
    pub normal: [f64; 3],
}

/// Per-thread scratch of [`SurfaceDistance::closest`] (the expansion's evaluation at arbitrary
/// parameters).
pub struct DistanceScratch {
    point: PointEval,
}

impl DistanceScratch {
    /// Scratch for surfaces of order `p`.
    pub fn new(p: usize) -> Self {
        DistanceScratch {
            point: PointEval::new(p),
        }
    }
}

/// One surface prepared for distance queries: its coefficients, the order-`q` samples, its
/// centre (the `Y_0^0` term) and reach (largest distance of a sample from the centre).
#[derive(Clone, Debug)]
pub struct SurfaceDistance {
    lay: CoefLayout,
    coefs: Vec<f64>,
    samples: Vec<[f64; 3]>,
    angles: Vec<(f64, f64)>,
    centre: [f64; 3],
    reach: f64,
    spacing: f64,
}

impl SurfaceDistance {
    /// The surface of order `p` with coefficients `coefs`, sampled on the grid of `sht`'s order
    /// `q ≥ p`.
    pub fn new(p: usize, coefs: &[f64], sht: &ShTransform) -> Result<Self, VesicleError> {
        let q = sht.order();
        if q < p {
            return Err(VesicleError::Order { p, q });
        }
        let surface = Surface::from_coefs(p, coefs.to_vec())?;
        let pos = surface.resampled(q)?.grid_positions(sht)?;
        let n = pos.len() / 3;
        let samples: Vec<[f64; 3]> = (0..n)
            .map(|j| [pos[j], pos[n + j], pos[2 * n + j]])
            .collect();
        let grid = Grid::new(q);
        let angles = (0..n).map(|j| grid.angles(j)).collect();
        let nc = coefs.len() / 3;
        let s = 1.0 / (4.0 * std::f64::consts::PI).sqrt();
        let centre = [coefs[0] * s, coefs[nc] * s, coefs[2 * nc] * s];
        let reach = samples.iter().map(|x| dist(*x, centre)).fold(0.0, f64::max);
        // Largest distance between neighbouring samples, bounded by the longitude spacing at the
        // equator of a sphere of radius `reach`.
        let spacing = 2.0 * std::f64::consts::PI * reach / (2 * q) as f64;
        Ok(SurfaceDistance {
            lay: CoefLayout::new(p),
            coefs: coefs.to_vec(),
            samples,
            angles,
            centre,
            reach,
            spacing,
        })
    }

    /// The same surface translated by `d` (a periodic image).
    pub fn translated(&self, d: [f64; 3]) -> Self {
        let mut out = self.clone();
        let nc = out.coefs.len() / 3;
        let s = (4.0 * std::f64::consts::PI).sqrt();
        for (a, da) in d.iter().enumerate() {
            out.coefs[a * nc] += da * s;
            out.centre[a] += da;
        }
        for x in &mut out.samples {
            for (xa, da) in x.iter_mut().zip(d) {
                *xa += da;
            }
        }
        out
    }

    /// The order-`q` samples of the surface (grid points, latitude-major).
    pub fn samples(&self) -> &[[f64; 3]] {
        &self.samples
    }

    /// The centre `c_00 / √(4π)` (the constant term of the expansion).
    pub fn centre(&self) -> [f64; 3] {
        self.centre
    }

    /// The largest distance of a sample from [`SurfaceDistance::centre`].
    pub fn reach(&self) -> f64 {
        self.reach
    }

    /// The closest point to `x` when it lies within `far` of the surface; otherwise `None`
    /// (the nearest sample, less the sample spacing, is farther than `far`).
    pub fn closest_within(
        &self,
        scratch: &mut DistanceScratch,
        x: [f64; 3],
        far: f64,
    ) -> Option<Closest> {
        if dist(x, self.centre) > self.reach + far {
            return None;
        }
        let (mut best, mut jbest) = (f64::INFINITY, 0);
        for (j, y) in self.samples.iter().enumerate() {
            let d2 = dist2(x, *y);
            if d2 < best {
                best = d2;
                jbest = j;
            }
        }
        if best.sqrt() - self.spacing > far {
            return None;
        }
        Some(self.newton(scratch, x, jbest))
    }

    /// Every sample of this surface within `range` of `other` (signed distance below `range`),
    /// with its closest point on `other`; and, when the nearest of them is outside `other`,
    /// the pair of closest points of the two continuous surfaces near it
    /// ([`SurfaceDistance::closest_pair`]) if it is closer still (between samples the surfaces
    /// can come closer than at any sample).
    pub fn gaps_to(
        &self,
        other: &SurfaceDistance,
        scratch: &mut DistanceScratch,
        range: f64,
    ) -> Vec<([f64; 3], Closest)> {
        let mut out = Vec::new();
        let mut nearest: Option<(usize, f64)> = None;
        for (j, &x) in self.samples.iter().enumerate() {
            let Some(cl) = other.closest_within(scratch, x, range) else {
                continue;
            };
            if cl.distance >= range {
                continue;
            }
            if nearest.is_none_or(|(_, g)| cl.distance < g) {
                nearest = Some((j, cl.distance));
            }
            out.push((x, cl));
        }
        if let Some((j, g0)) = nearest.filter(|n| n.1 > 0.0) {
            let (x, cl) = self.closest_pair(scratch, other, j);
            if cl.distance < g0 {
                out.push((x, cl));
            }
        }
        out
    }

    /// The closest point to `x` (Newton from the nearest sample).
    pub fn closest(&self, scratch: &mut DistanceScratch, x: [f64; 3]) -> Closest {
        self.closest_within(scratch, x, f64::INFINITY)
            .expect("an infinite range holds every point")
    }

    /// The pair of closest points of this surface and `other` near this surface's sample
    /// `start`: the signed distance `d(u)` from `X(u)` to `other` minimised over this surface's
    /// parameters `u = (θ, φ)` by Newton's method, with the exact gradient `∇d = n · X_u` (`n`
    /// the other surface's normal at the closest point) and the Hessian from forward
    /// differences of it; a step that does not lower `d` is halved. Returns the point of this
    /// surface and its closest point on `other`.
    pub fn closest_pair(
        &self,
        scratch: &mut DistanceScratch,
        other: &SurfaceDistance,
        start: usize,
    ) -> ([f64; 3], Closest) {
        self.closest_pair_by(scratch, start, 1.0, |s, x| other.closest(s, x))
    }

    /// [`Self::closest_pair`] with a surface `other` of another order (its own scratch
    /// `other_scratch`), from the inside when `inside`: for a closed surface `other` holding
    /// this one, the signed distance is maximised (the point of this surface nearest to
    /// `other` from within).
    pub fn closest_pair_to(
        &self,
        scratch: &mut DistanceScratch,
        other: &SurfaceDistance,
        other_scratch: &mut DistanceScratch,
        start: usize,
        inside: bool,
    ) -> ([f64; 3], Closest) {
        let sign = if inside { -1.0 } else { 1.0 };
        self.closest_pair_by(scratch, start, sign, |_, x| other.closest(other_scratch, x))
    }

    /// The Newton search of [`Self::closest_pair`] on `sign · d(u)`, `closest` the other
    /// surface's closest point to a point.
    fn closest_pair_by(
        &self,
        scratch: &mut DistanceScratch,
        start: usize,
        sign: f64,
        mut closest: impl FnMut(&mut DistanceScratch, [f64; 3]) -> Closest,
    ) -> ([f64; 3], Closest) {
        let mut eval = |scratch: &mut DistanceScratch, u: (f64, f64)| {
            let pd = scratch.point.eval(&self.lay, &self.coefs, u.0, u.1);
            let cl = closest(scratch, pd.x);
            let g = [sign * dot(cl.normal, pd.xt), sign * dot(cl.normal, pd.xp)];
            (pd.x, cl, g)
        };
        let mut u = self.angles[start];
        let (mut x, mut cl, mut g) = eval(scratch, u);
        let h = 1e-6;
        for _ in 0..30 {
            let (_, _, gt) = eval(scratch, (u.0 + h, u.1));
            let (_, _, gp) = eval(scratch, (u.0, u.1 + h));
            let (a, b, c) = (
                (gt[0] - g[0]) / h,
                0.5 * ((gt[1] - g[1]) / h + (gp[0] - g[0]) / h),
                (gp[1] - g[1]) / h,
            );
            let det = a * c - b * b;
            let mut step = if det > 0.0 && a > 0.0 {
                [-(c * g[0] - b * g[1]) / det, -(a * g[1] - b * g[0]) / det]
            } else {
                // Not convex here: a gradient step of at most 0.05 rad.
                let n = (g[0] * g[0] + g[1] * g[1]).sqrt().max(f64::MIN_POSITIVE);
                [-0.05 * g[0] / n, -0.05 * g[1] / n]
            };
            let mut accepted = false;
            for _ in 0..20 {
                let trial = (u.0 + step[0], u.1 + step[1]);
                let (xt, ct, gt) = eval(scratch, trial);
                if sign * ct.distance < sign * cl.distance {
                    (u, x, cl, g) = (trial, xt, ct, gt);
                    accepted = true;
                    break;
                }
                step = step.map(|v| 0.5 * v);
            }
            if !accepted || step[0].abs() + step[1].abs() < 1e-13 {
                break;
            }
        }
        (x, cl)
    }

    fn newton(&self, scratch: &mut DistanceScratch, x: [f64; 3], start: usize) -> Closest {
        let (u, pd) = closest_point(
            &mut scratch.point,
            &self.lay,
            &self.coefs,
            x,
            self.angles[start],
        );
        let mut y = pd.x;
        // The limit normal where the closest point is a pole.
        let mut nv = scratch.point.normal(&self.lay, &self.coefs, u, &pd);
        // Newton can stall at a pole's degenerate parametrisation; the nearest sample is then
        // the better answer (its normal from the neighbouring surface directions is not known,
        // so take the direction from the centre as the fallback normal).
        let sample = self.samples[start];
        if dist2(x, y).is_nan() || dist2(x, y) > dist2(x, sample) {
            y = sample;
            nv = [
                sample[0] - self.centre[0],
                sample[1] - self.centre[1],
                sample[2] - self.centre[2],
            ];
        }
        let len = dot(nv, nv).sqrt();
        let normal = if len > 0.0 {
            nv.map(|v| v / len)
        } else {
            [0.0, 0.0, 1.0]
        };
        let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
        let d = dot(r, r).sqrt();
        Closest {
            distance: if dot(r, normal) < 0.0 { -d } else { d },
            point: y,
            normal,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::shapes;

    /// A sphere: the signed distance is `|x − c| − r` and the normal is radial, inside and out.
    #[test]
    fn sphere_distance_is_exact() {
        let p = 6;
        let mut s = shapes::sphere(p, 1.3).unwrap();
        s.translate([0.2, -0.4, 0.1]);
        let sht = ShTransform::new(2 * p).unwrap();
        let sd = SurfaceDistance::new(p, s.coefs(), &sht).unwrap();
        let mut scratch = DistanceScratch::new(p);
        let c = [0.2, -0.4, 0.1];
        for x in [
            [2.0, 0.3, -0.5],
            [0.5, -0.1, 0.4],
            [0.2, -0.4, 1.45],
            // On the axis below the south pole, where `X_θ × X_φ` vanishes.
            [0.2, -0.4, -2.5],
            [-1.0, 0.9, 0.7],
            [0.21, -0.38, 0.12],
        ] {
            let got = sd.closest(&mut scratch, x);
            let r = dist(x, c);
            assert!((got.distance - (r - 1.3)).abs() < 1e-12, "{x:?}: {got:?}");
            for k in 0..3 {
                assert!((got.normal[k] - (x[k] - c[k]) / r).abs() < 1e-9);
            }
        }
    }

    /// A red blood cell, tilted: the Newton distance is at most the brute-force minimum over
    /// an order-96 grid and within that grid's resolution of it; the sign says inside.
    #[test]
    fn rbc_distance_matches_a_fine_grid() {
        let p = 8;
        let mut s = shapes::rbc(p).unwrap();
        let r = crate::linalg3::rotation_from_vector([0.55, 0.27, 0.11]);
        s.rotate(r).unwrap();
        let sht = ShTransform::new(2 * p).unwrap();
        let sd = SurfaceDistance::new(p, s.coefs(), &sht).unwrap();
        let fine_sht = ShTransform::new(96).unwrap();
        let fine = SurfaceDistance::new(p, s.coefs(), &fine_sht).unwrap();
        let mut scratch = DistanceScratch::new(p);
        let mut worst = 0.0f64;
        for x in [
            [1.5, 0.2, 0.3],
            [0.0, 0.0, 0.6],
            [0.3, 0.2, 0.0],
            [-1.1, 0.4, -0.2],
            [0.05, 1.2, 0.1],
        ] {
            let got = sd.closest(&mut scratch, x);
            let brute = fine
                .samples()
                .iter()
                .map(|y| dist(x, *y))
                .fold(f64::INFINITY, f64::min);
            assert!(got.distance.abs() <= brute + 1e-12, "{x:?}");
            worst = worst.max(brute - got.distance.abs());
            assert!(dist(x, got.point) - got.distance.abs() < 1e-12);
        }
        // Order-96 spacing about 2π·1.4/192 ≈ 0.046; a sample is within half of it.
        assert!(worst < 2e-3, "{worst}");
        // The centre of an RBC is inside it (the dimple is thin, not a hole); far away is out.
        assert!(sd.closest(&mut scratch, [0.0, 0.0, 0.0]).distance < 0.0);
        assert!(sd.closest(&mut scratch, [0.0, 0.0, 3.0]).distance > 2.0);
        assert!(sd
            .closest_within(&mut scratch, [0.0, 0.0, 3.0], 0.5)
            .is_none());
    }

    /// The closest pair of two spheres of different orders, from outside (a sphere beside a
    /// body) and from inside (a sphere in a container): the exact gaps `|c₁ − c₂| − r₁ − r₂` and
    /// `R − |c₁ − c₂| − r₁`, found by Newton from the nearest sample, where the samples
    /// themselves miss the closest point.
    #[test]
    fn closest_pair_to_finds_the_exact_gap_of_two_spheres() {
        let (p, q) = (6, 16);
        let mut small = shapes::sphere(p, 0.7).unwrap();
        // Off every grid direction of the small sphere's samples.
        let c1 = [0.31, -0.17, 0.23];
        small.translate(c1);
        let sd = SurfaceDistance::new(p, small.coefs(), &ShTransform::new(2 * p).unwrap()).unwrap();
        let (mut own, mut other) = (DistanceScratch::new(p), DistanceScratch::new(q));
        for (inside, radius, c2) in [
            (false, 1.1, [2.43, 0.91, -0.37]),
            (true, 2.6, [-0.12, 0.05, 0.08]),
        ] {
            let mut big = shapes::sphere(q, radius).unwrap();
            big.translate(c2);
            let wall =
                SurfaceDistance::new(q, big.coefs(), &ShTransform::new(2 * q).unwrap()).unwrap();
            let d = dist(c1, c2);
            let exact = if inside {
                radius - d - 0.7
            } else {
                d - radius - 0.7
            };
            let gap = |cl: &Closest| if inside { -cl.distance } else { cl.distance };
            let (start, sampled) = sd
                .samples()
                .iter()
                .map(|&x| gap(&wall.closest(&mut other, x)))
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |b, (j, g)| if g < b.1 { (j, g) } else { b },
                );
            let (x, cl) = sd.closest_pair_to(&mut own, &wall, &mut other, start, inside);
            assert!(
                sampled - exact > 1e-4,
                "the samples already hold it: {sampled} vs {exact}"
            );
            assert!(
                (gap(&cl) - exact).abs() < 1e-10,
                "{inside}: {} vs {exact}",
                gap(&cl)
            );
            assert!(
                (dist(x, c1) - 0.7).abs() < 1e-12,
                "{x:?} is on the small sphere"
            );
        }
    }
}
