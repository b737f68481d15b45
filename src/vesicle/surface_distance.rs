//! The signed distance from a point to a cell's surface, with the closest surface point and the
//! outward normal there: what contacts and the overlap test of a scene measure gaps with.
//!
//! The surface `X(θ, φ) = Σ c_nm Y_n^m(θ, φ)` is sampled on the grid of an order `q ≥ p`
//! (spacing about `2π R_max / (2q)`); the nearest sample starts Newton's method on
//! `½ |X(θ, φ) − x|²` (the crate's closest-point solve), which converges to the closest point
//! `y` of the continuous surface (where it ends farther than that sample, the next nearest
//! samples start it again, and failing those the nearest sample is the answer). The distance is `|x − y|`, negative when `x − y` points against the
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

/// The most Newton searches for the closest pair of two surfaces from one surface's samples
/// ([`SurfaceDistance::pair_starts`]).
pub const MAX_PAIR_STARTS: usize = 12;

/// How many of the nearest samples Newton's closest point may start from
/// ([`SurfaceDistance::closest_within`]).
const NEWTON_STARTS: usize = 4;

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
    /// Samples per latitude of the grid (`2q`).
    n_lon: usize,
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
            n_lon: grid.n_lon(),
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

    /// Samples per latitude of the grid of [`Self::samples`] (`2q`).
    pub fn n_lon(&self) -> usize {
        self.n_lon
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
        // The `NEWTON_STARTS` nearest samples, nearest first.
        let mut near = [(f64::INFINITY, 0usize); NEWTON_STARTS];
        for (j, y) in self.samples.iter().enumerate() {
            let d2 = dist2(x, *y);
            if d2 < near[NEWTON_STARTS - 1].0 {
                let mut k = NEWTON_STARTS - 1;
                while k > 0 && near[k - 1].0 > d2 {
                    near[k] = near[k - 1];
                    k -= 1;
                }
                near[k] = (d2, j);
            }
        }
        if near[0].0.sqrt() - self.spacing > far {
            return None;
        }
        let found = near.iter().take_while(|s| s.0.is_finite()).count();
        let starts = near.map(|s| s.1);
        Some(self.newton(scratch, x, &starts[..found]))
    }

    /// Every sample of this surface within `range` of `other` (signed distance below `range`),
    /// with its closest point on `other`; and, from each of the samples that
    /// [`Self::pair_starts`] picks, the pair of closest points of the two continuous surfaces
    /// near it ([`SurfaceDistance::closest_pair`]) if it is closer still (between samples the
    /// surfaces can come closer than at any sample).
    pub fn gaps_to(
        &self,
        other: &SurfaceDistance,
        scratch: &mut DistanceScratch,
        range: f64,
    ) -> Vec<([f64; 3], Closest)> {
        let mut out = Vec::new();
        let mut near: Vec<(usize, f64)> = Vec::new();
        for (j, &x) in self.samples.iter().enumerate() {
            let Some(cl) = other.closest_within(scratch, x, range) else {
                continue;
            };
            if cl.distance >= range {
                continue;
            }
            near.push((j, cl.distance));
            out.push((x, cl));
        }
        for (j, g0) in self.pair_starts(&near) {
            let (x, cl) = self.closest_pair(scratch, other, j);
            if cl.distance < g0 {
                out.push((x, cl));
            }
        }
        out
    }

    /// Where to start the Newton search for the closest pair of two surfaces, given the samples
    /// of this one near the other, `(sample, its gap)`: the samples outside the other whose gap
    /// is a minimum along their latitude or along their longitude (no larger than both grid
    /// neighbours on that line; a neighbour not near counts as larger), smallest first, each
    /// kept unless a kept one lies within 1.5 sample spacings; at most [`MAX_PAIR_STARTS`].
    /// A local minimum over every near sample within 1.5 spacings (the rule before) misses a
    /// thin ridge such as a red cell's rim against a wall: its samples lie off the crest, the
    /// sampled gap falls along the rim to another place, and the crest's own minimum between
    /// them is never started from (the 45 % Couette shell's cell 15 at step 950: measured
    /// 1.001 `d_min` from its container, 0.987 `d_min` on a fine grid). Across a ridge the gap
    /// has a minimum along any grid line that crosses it. With the nearest sample alone, a
    /// second place where a bent cell comes close to a wall was measured at its samples only,
    /// 5 % of `d_min` above the true gap (docs/hard_cases.md).
    pub fn pair_starts(&self, near: &[(usize, f64)]) -> Vec<(usize, f64)> {
        let mut gap = vec![f64::INFINITY; self.samples.len()];
        for &(j, g) in near {
            gap[j] = g;
        }
        let nl = self.n_lon;
        let n_lat = self.samples.len() / nl;
        let at = |i: usize, k: usize| gap[i * nl + k % nl];
        let mut candidates: Vec<(usize, f64)> = near
            .iter()
            .filter(|&&(j, g)| {
                let (i, k) = (j / nl, j % nl);
                let up = if i > 0 { at(i - 1, k) } else { f64::INFINITY };
                let down = if i + 1 < n_lat {
                    at(i + 1, k)
                } else {
                    f64::INFINITY
                };
                let along_latitude = g <= at(i, k + nl - 1) && g <= at(i, k + 1);
                g > 0.0 && ((g <= up && g <= down) || along_latitude)
            })
            .copied()
            .collect();
        candidates.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        let reach2 = (1.5 * self.spacing).powi(2);
        let mut starts: Vec<(usize, f64)> = Vec::new();
        for (j, g) in candidates {
            if starts.len() == MAX_PAIR_STARTS {
                break;
            }
            if starts
                .iter()
                .all(|&(k, _)| dist2(self.samples[j], self.samples[k]) > reach2)
            {
                starts.push((j, g));
            }
        }
        starts
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

    /// The point of this surface nearest to the plane `normal · x = offset` (`normal` a unit
    /// vector into the side the surface lies on), near the sample `start`: the height
    /// `normal · X(u) − offset` minimised over the parameters by the Newton search of
    /// [`Self::closest_pair`] (the plane's closest point to `x` is `x − d normal`, its normal
    /// `normal`). Returns the surface point and its projection on the plane, with the height as
    /// the distance. Measured at the samples alone, a curved body tilted towards a plane comes
    /// closer than its nearest sample between the samples.
    pub fn closest_to_plane(
        &self,
        scratch: &mut DistanceScratch,
        normal: [f64; 3],
        offset: f64,
        start: usize,
    ) -> ([f64; 3], Closest) {
        self.closest_pair_by(scratch, start, 1.0, |_, x| {
            let d = dot(normal, x) - offset;
            Closest {
                distance: d,
                point: [
                    x[0] - d * normal[0],
                    x[1] - d * normal[1],
                    x[2] - d * normal[2],
                ],
                normal,
            }
        })
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

    /// Newton's closest point from each of `starts` (samples, nearest first, at least one)
    /// until one ends no farther than the nearest sample. Newton can stall at a pole's degenerate
    /// parametrisation, or end at a critical point of the distance that is not its minimum (a
    /// point beside a strongly deformed cell, whose nearest sample is far from the closest
    /// point); if every start does, the nearest sample is the answer, with the surface's own
    /// normal there. (The direction from the centre, taken as that normal before, points the
    /// wrong way near a red cell's dimple and beside a bent one: the sign flipped, and points
    /// 0.4–0.7 outside a cell of the 45 % Couette shell read as that deep inside.)
    fn newton(&self, scratch: &mut DistanceScratch, x: [f64; 3], starts: &[usize]) -> Closest {
        let first = starts[0];
        let mut found: Option<([f64; 3], [f64; 3])> = None;
        for &start in starts {
            let (u, pd) = closest_point(
                &mut scratch.point,
                &self.lay,
                &self.coefs,
                x,
                self.angles[start],
            );
            // The limit normal where the closest point is a pole.
            let nv = scratch.point.normal(&self.lay, &self.coefs, u, &pd);
            let d2 = dist2(x, pd.x);
            if !d2.is_nan() && d2 <= dist2(x, self.samples[first]) {
                found = Some((pd.x, nv));
                break;
            }
        }
        let (y, nv) = found.unwrap_or_else(|| {
            let u = self.angles[first];
            let pd = scratch.point.eval(&self.lay, &self.coefs, u.0, u.1);
            let nv = scratch.point.normal(&self.lay, &self.coefs, u, &pd);
            (self.samples[first], nv)
        });
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

/// The numbers of a text file, one per line after `#` comments (a cell's coefficients kept
/// from a run in tests/data).
#[cfg(test)]
pub(crate) fn coefs_from_text(text: &str) -> Vec<f64> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.parse().expect("one number a line"))
        .collect()
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

    /// Points around a tilted red cell, 0.05–0.8 from it (random, in its bounding box grown
    /// by 0.8): the signed distance has the sign of the nearest point of an order-96 grid
    /// (whose normal is exact there), is never above the distance to that grid in size, and
    /// is within the grid's resolution of it. Where Newton ended farther than the nearest
    /// sample, the sample was taken with the direction from the cell's centre as its normal,
    /// which near the dimple can point the wrong way: the sign flipped, and a point 0.4–0.7
    /// outside read as that deep inside (spurious overlaps of −0.37 to −0.71 in the frames of
    /// the 45 % Couette shell of docs/hard_cases.md).
    #[test]
    fn the_sign_of_the_distance_around_a_red_cell_is_right() {
        let p = 8;
        let mut s = shapes::rbc(p).unwrap();
        s.rotate(crate::linalg3::rotation_from_vector([0.35, -0.2, 0.1]))
            .unwrap();
        let sd = SurfaceDistance::new(p, s.coefs(), &ShTransform::new(2 * p).unwrap()).unwrap();
        let fine = SurfaceDistance::new(p, s.coefs(), &ShTransform::new(96).unwrap()).unwrap();
        let mut scratch = DistanceScratch::new(p);
        let (mut seed, mut checked, mut worst) = (99u64, 0, 0.0f64);
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        while checked < 3000 {
            let x = [next(), next(), next()].map(|v| (2.0 * v - 1.0) * 2.3);
            let (z, brute) = fine.samples().iter().map(|&z| (z, dist(x, z))).fold(
                ([0.0; 3], f64::INFINITY),
                |b, a| if a.1 < b.1 { a } else { b },
            );
            if !(0.05..=0.8).contains(&brute) {
                continue;
            }
            let n = sd.closest(&mut scratch, z).normal;
            let outside = dot([x[0] - z[0], x[1] - z[1], x[2] - z[2]], n) > 0.0;
            let got = sd.closest(&mut scratch, x).distance;
            assert_eq!(got > 0.0, outside, "{x:?}: {got} (brute {brute})");
            assert!(got.abs() <= brute + 1e-12, "{x:?}: {got} against {brute}");
            worst = worst.max(brute - got.abs());
            checked += 1;
        }
        // Newton's point may lie between the order-96 samples, by their sagitta near the rim.
        assert!(worst < 1e-2, "{worst}");
    }

    /// The case that showed it: a red cell bent in the 45 % Couette shell (its coefficients
    /// in tests/data) and a point of its neighbour's surface beside it. Newton ended farther
    /// than the nearest sample from the nearest one, and the sample, with the direction from
    /// the centre as its normal, read as 0.709 inside. The point is outside, its distance the
    /// fine grid's to within the coarse samples' resolution.
    #[test]
    fn a_point_beside_a_bent_red_cell_is_outside() {
        let coefs = coefs_from_text(include_str!("../../tests/data/deformed_rbc_p8.txt"));
        let p = 8;
        let sd = SurfaceDistance::new(p, &coefs, &ShTransform::new(2 * p).unwrap()).unwrap();
        let fine = SurfaceDistance::new(p, &coefs, &ShTransform::new(96).unwrap()).unwrap();
        let x = [
            -0.5966901557375344,
            -2.1045216218152074,
            -0.8972778930792493,
        ];
        let brute = fine
            .samples()
            .iter()
            .map(|&z| dist(x, z))
            .fold(f64::INFINITY, f64::min);
        let got = sd.closest(&mut DistanceScratch::new(p), x).distance;
        // At 0.7 from the cell, more than its rim's radius of curvature, Newton's Hessian is
        // indefinite and no start converges: the nearest order-16 sample is the answer, a
        // little above the fine grid's distance.
        assert!(
            got > 0.0 && (got - brute).abs() < 1e-2,
            "{got} against {brute}"
        );
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
