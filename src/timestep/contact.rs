//! Contacts: a projection that leaves every pair of cell surfaces (and every cell and a plane
//! wall) at least `d_min` apart.
//!
//! **What is guaranteed, and where it is measured.** Gaps are signed distances from the samples
//! of one surface (its grid of order `q = 2p`) to the other, continuous, surface
//! ([`SurfaceDistance`]: Newton's closest point), both ways round; from the minima of the
//! sampled gap along the grid's lines ([`SurfaceDistance::pair_starts`]), Newton's method over
//! the first surface's parameters ([`SurfaceDistance::closest_pair`]) finds a pair of closest
//! points of the two continuous surfaces, whose distance is measured too. Against a plane
//! wall, the same search finds the body's least height above the plane between its samples
//! ([`SurfaceDistance::closest_to_plane`]). [`ContactSolver::resolve`] returns only
//! when every such gap is at least `d_min`, or fails with the smallest gap left.
//!
//! **The projection.** Each body moves rigidly: a translation `t_a` and, when rotations are
//! allowed, a small rotation `θ_a` about its centre `c_a`. A sample `x` of body `a` whose closest
//! point on body `b` is `y`, with `b`'s outward normal `n` there and gap `g`, gives the
//! linearised constraint
//!
//! `g + n · (t_a + θ_a × (x − c_a)) − n · (t_b + θ_b × (y − c_b)) ≥ d_target`,
//!
//! i.e. `g + J v ≥ d_target` with the rows `[n, (x − c_a) × n]` and `[−n, −(y − c_b) × n]`.
//! The move is the smallest one in the metric `M = diag(1, 1, 1, R², R², R²)` (`R` the body's
//! reach): `min ½ vᵀ M v` subject to the constraints, a convex quadratic program whose dual is the
//! linear complementarity problem `0 ≤ λ ⊥ g + J M⁻¹ Jᵀ λ − d_target ≥ 0`, solved by projected
//! Gauss–Seidel (Moreau's and Jean's contact dynamics). In a time step a gap below `d_min` is
//! pushed past `d_min` by its own deficit `d_min − g` (at least a slack `s = 10⁻³ d_min`, at
//! most `0.2 d_min`), so that the curvature neglected by the linearisation, second order in
//! the move, is absorbed; a gap already at least `d_min` (within `3 d_min`) only has to stay at
//! `d_min + s`. Asking every gap in reach for `1.2 d_min` asks a jammed suspension for more
//! room than it has (16 RBCs at 45 % of a Couette shell: the linearised problem had no
//! solution, and the rounds swung between two pairs at 0.99 `d_min` until they gave up), and
//! a fixed `0.2 d_min` overshoot on a gap that lacks `10⁻³ d_min` moved a jam by `0.8 d_min`,
//! whose curvature error then opened new deficits elsewhere. After a round in which the
//! smallest gap did not grow, a time step halves the margin and the slack above `d_min`
//! (1.2, 1.1, 1.05 … `d_min`), for a jam with less room. A packing
//! ([`ContactParams::spread`]) pushes every gap in reach to the full `1.2 d_min`. The gaps are
//! then measured again at the moved surfaces, and the rounds repeat until every gap is at
//! least `d_min` (or fail after `max_rounds`, or after `stall_rounds` rounds in which the
//! smallest gap grew neither by `10⁻³ d_min` nor by half of what it lacked).
//!
//! This is the position-level counterpart of the space-time interference volumes of Lu,
//! Rahimian & Zorin (J. Comput. Phys. 347, 2017): the same guarantee (no pair closer than
//! `d_min` at the end of a step), with the contact impulse distributed by the rigid-body metric
//! `M` instead of the cells' Stokes mobility. A rigid move changes no shape, area or volume.
//!
//! **Periodic images.** With [`ContactParams::period`] a vector `P`, the bodies are also kept
//! `d_min` from each other's images `x + P` (the periodic packing of a tube's recycling window,
//! [`crate::scene::packing`]): a sample of body `a` near the image of body `b` gives the same
//! constraint with `c_b + P` in place of `c_b`, and a move of `b` moves its image alike. Each
//! pair across the period is measured once (against the images shifted by `+P`).

use rayon::prelude::*;

use crate::linalg3::{cross3, dist3 as dist, dot3, matmul3, rotation_from_vector, sub3};
use crate::sph_harmonics::ShTransform;
use crate::vesicle::surface_distance::{DistanceScratch, SurfaceDistance};
use crate::vesicle::VesicleError;

pub use super::fixed_surface::FixedSurface;

/// The margin `d_target / d_min` the projection aims at.
const OVERSHOOT: f64 = 1.2;

/// A time step's slack above `d_min` for gaps at or near it, relative to `d_min`, at the full
/// margin (ten times projected Gauss–Seidel's tolerance; [`target`]).
const SLACK: f64 = 1e-3;

/// Gaps below `RANGE · d_min` enter the projection as constraints (met ones stay inactive but
/// keep a move from pushing their points through).
const RANGE: f64 = 3.0;

/// Largest rotation of one round, in radians (the linearisation's domain).
const MAX_TURN: f64 = 0.1;

/// Errors of the contact projection.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ContactError {
    /// A surface could not be prepared for distance queries (the surface error's message).
    #[error("contact: {0}")]
    Vesicle(String),
    /// `d_min` outside `(0, ∞)`.
    #[error("contact distance d_min = {0} must be positive and finite")]
    Distance(f64),
    /// Bodies of different orders or lengths.
    #[error("contact: body {body} has {len} coefficients, expected {expected}")]
    Length {
        /// The body.
        body: usize,
        /// Its number of coefficients.
        len: usize,
        /// The number of order `p`.
        expected: usize,
    },
    /// The rounds ran out, or stalled, with a gap below `d_min`.
    #[error(
        "contacts unresolved after {rounds} rounds: the smallest gap is {gap:.3e} < d_min = \
         {d_min:.3e}, between body {a} and {}",
        match .b { Some(b) => format!("body {b}"), None => "a wall".to_string() }
    )]
    Unresolved {
        /// Rounds made.
        rounds: usize,
        /// The smallest gap left.
        gap: f64,
        /// The distance asked for.
        d_min: f64,
        /// The body whose sample is closest.
        a: usize,
        /// The other body (`None`: a wall).
        b: Option<usize>,
    },
    /// A period too short for the bodies: one would meet its own image.
    #[error(
        "contact: the period {period:.3e} is shorter than twice body {body}'s reach {reach:.3e} \
         plus the range {range:.3e}: the body would meet its own image"
    )]
    Period {
        /// The period's length.
        period: f64,
        /// The body.
        body: usize,
        /// Its reach.
        reach: f64,
        /// The range within which gaps are measured.
        range: f64,
    },
}

impl From<VesicleError> for ContactError {
    fn from(e: VesicleError) -> Self {
        ContactError::Vesicle(e.to_string())
    }
}

/// What the projection guarantees and how it may move bodies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactParams {
    /// The smallest gap `d_min` left between surfaces (and between a surface and a wall).
    pub distance: f64,
    /// Whether bodies may turn as well as translate (a packing; a suspension's step, which
    /// moves each cell with its whole history rigidly, `timestep::suspension`'s contacts) or
    /// only translate (the default of [`ContactParams::new`]). A body wedged between others
    /// or walls may have room only by turning (module docs).
    pub rotations: bool,
    /// Rounds of measure-and-project before giving up.
    pub max_rounds: usize,
    /// Rounds without the smallest gap growing (by `10⁻³ d_min`, or by half of what it lacked
    /// of `d_min`) after which the projection gives up (an infeasible set: cells jammed
    /// between others or walls).
    pub stall_rounds: usize,
    /// Whether every gap in reach is pushed to the margin `1.2 d_min` (a packing: room ahead
    /// of the next growth) or only the gaps below `d_min` past it, by their deficit, the met
    /// ones kept at `d_min` plus a slack (a time step: the least move; module docs).
    pub spread: bool,
    /// The bodies' images shifted by this vector keep `d_min` from the bodies as well (module
    /// docs; `None`: no images). It must exceed twice a body's reach plus `3 d_min`.
    pub period: Option<[f64; 3]>,
}

impl ContactParams {
    /// Translations only, at most 30 rounds, giving up after 5 stalled ones, met gaps kept at
    /// `d_min`.
    pub fn new(distance: f64) -> Self {
        ContactParams {
            distance,
            rotations: false,
            max_rounds: 30,
            stall_rounds: 5,
            spread: false,
            period: None,
        }
    }
}

/// A plane wall: the allowed side is `normal · x ≥ offset` (`normal` a unit vector).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wall {
    /// Unit normal into the allowed side.
    pub normal: [f64; 3],
    /// `normal · x` on the plane.
    pub offset: f64,
}

/// A rigid move of a body: `x ↦ centre + R (x − centre) + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// The centre of the rotation (the body's centre before the move).
    pub centre: [f64; 3],
    /// The rotation `R`.
    pub rotation: [[f64; 3]; 3],
    /// The translation.
    pub translation: [f64; 3],
}

impl Move {
    /// No move about `centre`.
    pub fn identity(centre: [f64; 3]) -> Self {
        Move {
            centre,
            rotation: rotation_from_vector([0.0; 3]),
            translation: [0.0; 3],
        }
    }

    /// Apply the move to the SH coefficients of a surface (`x` then `y` then `z`): every mode is
    /// rotated, the constant mode `Y_0^0 = 1/√(4π)` also shifted.
    pub fn apply(&self, coefs: &mut [f64]) {
        let nc = coefs.len() / 3;
        let r = &self.rotation;
        for i in 0..nc {
            let v = [coefs[i], coefs[nc + i], coefs[2 * nc + i]];
            for (a, row) in r.iter().enumerate() {
                coefs[a * nc + i] = dot3(*row, v);
            }
        }
        let rc: [f64; 3] = std::array::from_fn(|a| dot3(r[a], self.centre));
        let s = (4.0 * std::f64::consts::PI).sqrt();
        for a in 0..3 {
            coefs[a * nc] += (self.centre[a] - rc[a] + self.translation[a]) * s;
        }
    }

    /// Whether the move is the identity.
    pub fn is_identity(&self) -> bool {
        self.translation == [0.0; 3] && !self.turns()
    }

    /// Whether the move turns what it moves (its rotation is not the identity).
    pub fn turns(&self) -> bool {
        self.rotation != Move::identity(self.centre).rotation
    }
}

/// What a [`ContactSolver::resolve`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactOutcome {
    /// Per body, its move (identity for those left alone).
    pub moves: Vec<Move>,
    /// Rounds of projection made (0: no gap was below `d_min`).
    pub rounds: usize,
    /// Constraints that were active (positive multiplier) in the projections, summed over rounds.
    pub active: usize,
    /// Bodies moved.
    pub moved: usize,
    /// The smallest measured gap before (within `3 d_min`; infinite when none is that close).
    pub gap_before: f64,
    /// The smallest measured gap after.
    pub gap_after: f64,
}

/// What the contact projection did over a run's steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ContactStats {
    /// Steps that ran the projection.
    pub steps: usize,
    /// Steps in which some gap was below `d_min` (cells were moved).
    pub steps_with_moves: usize,
    /// Rounds of projection, summed.
    pub rounds: usize,
    /// Active contacts (positive multipliers), summed over the rounds.
    pub active: usize,
    /// Cell moves, summed over the steps.
    pub moves: usize,
    /// Seconds in the projection (gathering, measuring, solving, moving).
    pub seconds: f64,
    /// The smallest gap at the end of the last step, where below `3 d_min`.
    pub last_gap: Option<f64>,
    /// The smallest end-of-step gap over the steps, where below `3 d_min`.
    pub smallest_gap: Option<f64>,
}

/// One linearised contact.
struct Constraint {
    a: usize,
    b: Option<usize>,
    ja: [f64; 6],
    jb: [f64; 6],
    gap: f64,
}

impl Constraint {
    /// Body `a` (centre `c`) at its point `x`, `gap` from a fixed wall whose normal into the
    /// allowed side is `nm`: the row `[n, (x − c) × n]`.
    fn wall(a: usize, c: [f64; 3], x: [f64; 3], nm: [f64; 3], gap: f64) -> Self {
        let ra = cross3(sub3(x, c), nm);
        Constraint {
            a,
            b: None,
            ja: [nm[0], nm[1], nm[2], ra[0], ra[1], ra[2]],
            jb: [0.0; 6],
            gap,
        }
    }
}

/// Every body's distance surface, built by [`ContactSolver::prepare`]: the others' surfaces
/// against which places for one body are tried.
pub struct PreparedBodies {
    bodies: Vec<SurfaceDistance>,
}

/// The contact projection for bodies of SH order `p` (see the module docs).
pub struct ContactSolver {
    p: usize,
    params: ContactParams,
    sht: ShTransform,
}

impl ContactSolver {
    /// A solver for surfaces of order `p`, sampled at order `2p`.
    pub fn new(p: usize, params: ContactParams) -> Result<Self, ContactError> {
        if !(params.distance.is_finite() && params.distance > 0.0) {
            return Err(ContactError::Distance(params.distance));
        }
        Ok(ContactSolver {
            p,
            params,
            sht: ShTransform::new(2 * p).map_err(VesicleError::Sph)?,
        })
    }

    /// The parameters.
    pub fn params(&self) -> ContactParams {
        self.params
    }

    /// Move the bodies with `coefs` (order `p`, unchanged here) so that no gap is below
    /// `d_min`: the moves, or [`ContactError::Unresolved`].
    pub fn resolve(
        &self,
        coefs: &[&[f64]],
        walls: &[Wall],
    ) -> Result<ContactOutcome, ContactError> {
        self.resolve_with(coefs, walls, &[])
    }

    /// [`Self::resolve`] with fixed curved walls as well.
    pub fn resolve_with(
        &self,
        coefs: &[&[f64]],
        walls: &[Wall],
        fixed: &[FixedSurface],
    ) -> Result<ContactOutcome, ContactError> {
        let d_min = self.params.distance;
        let range = RANGE * d_min;
        let mut current: Vec<Vec<f64>> = coefs.iter().map(|c| c.to_vec()).collect();
        let mut bodies = self.bodies(coefs)?;
        let mut moves: Vec<Move> = bodies.iter().map(|b| Move::identity(b.centre())).collect();
        let (mut active, mut gap_before) = (0, f64::INFINITY);
        let (mut best, mut stalled) = (f64::NEG_INFINITY, 0);
        let mut margin = OVERSHOOT;
        for round in 0..=self.params.max_rounds {
            let images = self.images(&bodies, range)?;
            let (cons, least) = self.measure(&bodies, &images, walls, fixed, range, None);
            let gap = least.map_or(f64::INFINITY, |l| l.0);
            if round == 0 {
                gap_before = gap;
            }
            if gap >= d_min {
                let moved = moves.iter().filter(|m| !m.is_identity()).count();
                return Ok(ContactOutcome {
                    moves,
                    rounds: round,
                    active,
                    moved,
                    gap_before,
                    gap_after: gap,
                });
            }
            if progressed(gap, best, d_min) {
                (best, stalled) = (gap, 0);
            } else {
                stalled += 1;
                // A time step's stalled round: the margin the gaps below `d_min` are pushed to
                // may be more room than the jam has; ask for half as much above `d_min`.
                if !self.params.spread {
                    margin = 1.0 + 0.5 * (margin - 1.0);
                }
            }
            if round == self.params.max_rounds || stalled >= self.params.stall_rounds {
                let (gap, a, b) = least.expect("a gap below d_min was measured");
                return Err(ContactError::Unresolved {
                    rounds: round,
                    gap,
                    d_min,
                    a,
                    b,
                });
            }
            let (v, n_active) = self.project(&bodies, &cons, margin);
            active += n_active;
            let mut changed = Vec::new();
            for (k, vk) in v.iter().enumerate() {
                if vk.iter().all(|&x| x == 0.0) {
                    continue;
                }
                let mut turn = [vk[3], vk[4], vk[5]];
                let angle = dot3(turn, turn).sqrt();
                if angle > MAX_TURN {
                    turn = turn.map(|t| t * MAX_TURN / angle);
                }
                let step = Move {
                    centre: bodies[k].centre(),
                    rotation: rotation_from_vector(turn),
                    translation: [vk[0], vk[1], vk[2]],
                };
                step.apply(&mut current[k]);
                let m = &mut moves[k];
                m.rotation = matmul3(step.rotation, m.rotation);
                for a in 0..3 {
                    m.translation[a] += step.translation[a];
                }
                changed.push(k);
            }
            let rebuilt: Result<Vec<(usize, SurfaceDistance)>, ContactError> = changed
                .par_iter()
                .map(|&k| Ok((k, SurfaceDistance::new(self.p, &current[k], &self.sht)?)))
                .collect();
            for (k, b) in rebuilt? {
                bodies[k] = b;
            }
        }
        unreachable!("the last round returns")
    }

    /// Every body's distance surface, built once, for [`Self::first_clear_or_best`] to try
    /// places for one body against the others.
    pub fn prepare(&self, coefs: &[&[f64]]) -> Result<PreparedBodies, ContactError> {
        Ok(PreparedBodies {
            bodies: self.bodies(coefs)?,
        })
    }

    /// Body `k` of `prepared` now has `coefs`.
    pub fn set(
        &self,
        prepared: &mut PreparedBodies,
        k: usize,
        coefs: &[f64],
    ) -> Result<(), ContactError> {
        prepared.bodies[k] = self.bodies(&[coefs])?.remove(0);
        Ok(())
    }

    /// The first of the `places` (coefficients for body `k`, tried in order) where body `k`
    /// is at least `need` from every other body of `prepared` and every fixed surface, or,
    /// when none is, the place with the largest gap; with its gap (signed, negative where
    /// surfaces cross; measured within `range ≥ need`, `range` when nothing is that close):
    /// where a cell recycled through a tube may land ([`super::suspension::Recycling`]). Only
    /// the pairs with body `k` are measured; body `k` of `prepared` is left at the last place
    /// tried, so the caller [`Self::set`]s it to where the body stays.
    pub fn first_clear_or_best(
        &self,
        prepared: &mut PreparedBodies,
        k: usize,
        places: &[Vec<f64>],
        fixed: &[FixedSurface],
        need: f64,
        range: f64,
    ) -> Result<(usize, f64), ContactError> {
        let mut best = (0, f64::NEG_INFINITY);
        let smallest = |cons: Vec<Constraint>| cons.iter().map(|c| c.gap).fold(range, f64::min);
        for (i, place) in places.iter().enumerate() {
            let bodies = &mut prepared.bodies;
            bodies[k] = self.bodies(&[place])?.remove(0);
            // The other bodies first; the fixed surfaces (Newton's closest point on a large
            // wall at every sample: the dearer measure) only where the place can still be
            // taken, clear or better than the best so far.
            let (cons, _) = self.measure(bodies, &[], &[], &[], range, Some(k));
            let mut gap = smallest(cons);
            if gap >= need || gap > best.1 {
                let (cons, _) = self.measure(&bodies[k..=k], &[], &[], fixed, range, Some(0));
                gap = gap.min(smallest(cons));
            }
            if gap >= need {
                return Ok((i, gap));
            }
            if gap > best.1 {
                best = (i, gap);
            }
        }
        Ok(best)
    }

    /// The bodies' images shifted by the period (none without one), each with its body's
    /// index; an error when a body would meet its own image.
    fn images(
        &self,
        bodies: &[SurfaceDistance],
        range: f64,
    ) -> Result<Vec<(usize, SurfaceDistance)>, ContactError> {
        let Some(v) = self.params.period else {
            return Ok(Vec::new());
        };
        let period = dot3(v, v).sqrt();
        bodies
            .iter()
            .enumerate()
            .map(|(k, b)| {
                if period <= 2.0 * b.reach() + range {
                    return Err(ContactError::Period {
                        period,
                        body: k,
                        reach: b.reach(),
                        range,
                    });
                }
                Ok((k, b.translated(v)))
            })
            .collect()
    }

    fn bodies(&self, coefs: &[&[f64]]) -> Result<Vec<SurfaceDistance>, ContactError> {
        let expected = 3 * crate::sph_harmonics::CoefLayout::new(self.p).len();
        for (body, c) in coefs.iter().enumerate() {
            if c.len() != expected {
                return Err(ContactError::Length {
                    body,
                    len: c.len(),
                    expected,
                });
            }
        }
        coefs
            .par_iter()
            .map(|c| Ok(SurfaceDistance::new(self.p, c, &self.sht)?))
            .collect()
    }

    /// Every gap below `range` as a linearised constraint (deterministic order: pairs, pairs
    /// with images, then walls), and the smallest gap with its bodies; with `only`, just the
    /// gaps of that body.
    #[allow(clippy::type_complexity)]
    fn measure(
        &self,
        bodies: &[SurfaceDistance],
        images: &[(usize, SurfaceDistance)],
        walls: &[Wall],
        fixed: &[FixedSurface],
        range: f64,
        only: Option<usize>,
    ) -> (Vec<Constraint>, Option<(f64, usize, Option<usize>)>) {
        let n = bodies.len();
        let wanted = |i: usize, j: usize| only.is_none_or(|k| i == k || j == k);
        // (a, its surface, b, its surface): a's samples against b's surface.
        let mut pairs: Vec<(usize, &SurfaceDistance, usize, &SurfaceDistance)> = Vec::new();
        for i in 0..n {
            for j in i + 1..n {
                let d = dist(bodies[i].centre(), bodies[j].centre());
                if wanted(i, j) && d <= bodies[i].reach() + bodies[j].reach() + range {
                    pairs.push((i, &bodies[i], j, &bodies[j]));
                    pairs.push((j, &bodies[j], i, &bodies[i]));
                }
            }
        }
        for (i, body) in bodies.iter().enumerate() {
            for (j, image) in images {
                let d = dist(body.centre(), image.centre());
                if i != *j && wanted(i, *j) && d <= body.reach() + image.reach() + range {
                    pairs.push((i, body, *j, image));
                    pairs.push((*j, image, i, body));
                }
            }
        }
        let p = self.p;
        let mut cons: Vec<Constraint> = pairs
            .par_iter()
            .map_init(
                || DistanceScratch::new(p),
                |scratch, &(a, ba, b, bb)| {
                    let (ca, cb) = (ba.centre(), bb.centre());
                    ba.gaps_to(bb, scratch, range)
                        .into_iter()
                        .map(|(x, cl)| {
                            let nrm = cl.normal;
                            let ra = cross3(sub3(x, ca), nrm);
                            let rb = cross3(sub3(cl.point, cb), nrm);
                            Constraint {
                                a,
                                b: Some(b),
                                ja: [nrm[0], nrm[1], nrm[2], ra[0], ra[1], ra[2]],
                                jb: [-nrm[0], -nrm[1], -nrm[2], -rb[0], -rb[1], -rb[2]],
                                gap: cl.distance,
                            }
                        })
                        .collect::<Vec<_>>()
                },
            )
            .flatten()
            .collect();
        let mut own_scratch = DistanceScratch::new(p);
        for (a, body) in bodies.iter().enumerate() {
            if only.is_some_and(|k| k != a) {
                continue;
            }
            for w in walls {
                let c = body.centre();
                if dot3(w.normal, c) - w.offset > body.reach() + range {
                    continue;
                }
                let nm = w.normal;
                let mut push = |x: [f64; 3], g: f64| cons.push(Constraint::wall(a, c, x, nm, g));
                let mut near: Vec<(usize, f64)> = Vec::new();
                for (j, &x) in body.samples().iter().enumerate() {
                    let g = dot3(nm, x) - w.offset;
                    if g < range {
                        push(x, g);
                        near.push((j, g));
                    }
                }
                // Between the samples the body can come closer: Newton from each minimum
                // of the sampled height (as against curved walls below).
                for (j, g0) in body.pair_starts(&near) {
                    let (x, cl) = body.closest_to_plane(&mut own_scratch, nm, w.offset, j);
                    if cl.distance < g0 {
                        push(x, cl.distance);
                    }
                }
            }
        }
        for f in fixed {
            let (fs, container) = (f.surface(), f.is_container());
            let fc = fs.centre();
            // Each body against the wall in parallel, the constraints kept in body order.
            let per_body: Vec<Vec<Constraint>> = bodies
                .par_iter()
                .enumerate()
                .map_init(
                    || (DistanceScratch::new(f.order()), DistanceScratch::new(p)),
                    |(scratch, own), (a, body)| {
                        let mut out = Vec::new();
                        if only.is_some_and(|k| k != a) {
                            return out;
                        }
                        let c = body.centre();
                        let d = dist(c, fc);
                        let far = if container {
                            d + body.reach() + range < f.r_min()
                        } else {
                            d > body.reach() + fs.reach() + range
                        };
                        if far {
                            return out;
                        }
                        // Samples proven more than `range` from the wall on the allowed side
                        // take no Newton solve (`FixedSurface::clear_samples`).
                        let clear = f.clear_samples(body, scratch, range);
                        let mut near: Vec<(usize, f64)> = Vec::new();
                        for (j, &x) in body.samples().iter().enumerate() {
                            if clear[j] || (container && dist(x, fc) + range < f.r_min()) {
                                continue;
                            }
                            let cl = fs.closest(scratch, x);
                            let (g, nm) = f.gap_and_normal(&cl);
                            if g < range {
                                out.push(Constraint::wall(a, c, x, nm, g));
                                near.push((j, g));
                            }
                        }
                        // Between the samples the surfaces can come closer: Newton from each
                        // local minimum of the sampled gap (as between cells,
                        // `SurfaceDistance::gaps_to`).
                        for (j, g0) in body.pair_starts(&near) {
                            let (x, cl) = body.closest_pair_to(own, fs, scratch, j, container);
                            let (g, nm) = f.gap_and_normal(&cl);
                            if g < g0 {
                                out.push(Constraint::wall(a, c, x, nm, g));
                            }
                        }
                        out
                    },
                )
                .collect();
            cons.extend(per_body.into_iter().flatten());
        }
        let least = cons.iter().fold(
            None,
            |best: Option<(f64, usize, Option<usize>)>, c| match best {
                Some((g, _, _)) if g <= c.gap => best,
                _ => Some((c.gap, c.a, c.b)),
            },
        );
        (cons, least)
    }

    /// Projected Gauss–Seidel on the dual of `min ½ vᵀ M v` subject to `g + J v ≥ d_target`:
    /// the moves `v` per body and the number of active constraints.
    fn project(
        &self,
        bodies: &[SurfaceDistance],
        cons: &[Constraint],
        margin: f64,
    ) -> (Vec<[f64; 6]>, usize) {
        let (d_min, spread) = (self.params.distance, self.params.spread);
        let minv: Vec<[f64; 6]> = bodies
            .iter()
            .map(|b| {
                let w = if self.params.rotations {
                    1.0 / (b.reach() * b.reach()).max(f64::MIN_POSITIVE)
                } else {
                    0.0
                };
                [1.0, 1.0, 1.0, w, w, w]
            })
            .collect();
        let denom: Vec<f64> = cons
            .iter()
            .map(|c| {
                let mut d: f64 = (0..6).map(|k| c.ja[k] * c.ja[k] * minv[c.a][k]).sum();
                if let Some(b) = c.b {
                    d += (0..6).map(|k| c.jb[k] * c.jb[k] * minv[b][k]).sum::<f64>();
                }
                d
            })
            .collect();
        // Each constraint's target depends on its gap and the round's margin only.
        let goal: Vec<f64> = cons
            .iter()
            .map(|c| target(c.gap, d_min, spread, margin))
            .collect();
        let mut v = vec![[0.0; 6]; bodies.len()];
        let mut lambda = vec![0.0; cons.len()];
        let tol = 1e-4 * self.params.distance;
        for _ in 0..2000 {
            let mut change = 0.0f64;
            for (k, c) in cons.iter().enumerate() {
                let mut r = c.gap - goal[k] + dot6(c.ja, v[c.a]);
                if let Some(b) = c.b {
                    r += dot6(c.jb, v[b]);
                }
                let new = (lambda[k] - r / denom[k]).max(0.0);
                let dl = new - lambda[k];
                if dl == 0.0 {
                    continue;
                }
                lambda[k] = new;
                for i in 0..6 {
                    v[c.a][i] += minv[c.a][i] * c.ja[i] * dl;
                }
                if let Some(b) = c.b {
                    for i in 0..6 {
                        v[b][i] += minv[b][i] * c.jb[i] * dl;
                    }
                }
                change = change.max(dl.abs() * denom[k]);
            }
            if change < tol {
                break;
            }
        }
        (v, lambda.iter().filter(|&&l| l > 0.0).count())
    }
}

/// The gap a constraint of gap `gap` is pushed to. With `spread` (a packing): `margin · d_min`.
///
/// In a time step, a gap below `d_min` is pushed past `d_min` by its own deficit `d_min − gap`,
/// at least the slack `s` and at most `(margin − 1) d_min`: the curvature the linearisation
/// neglects is second order in the move, so a small deficit needs a small overshoot, and a jam
/// has no room for `0.2 d_min` more on a gap that lacks `10⁻⁵ d_min`. A met gap only has to
/// stay at `d_min + s`: kept from being pushed through, not pushed further (in a jam every gap
/// within reach asked for `1.2 d_min` is more room than there is). The slack
/// `s = SLACK · d_min · (margin − 1)/(OVERSHOOT − 1)` is ten times what projected Gauss–Seidel
/// leaves unconverged, so that a met gap does not end a hair below `d_min`; it halves with the
/// margin after each stalled round, for a jam with less room than that.
fn target(gap: f64, d_min: f64, spread: bool, margin: f64) -> f64 {
    if spread {
        return margin * d_min;
    }
    let slack = SLACK * d_min * (margin - 1.0) / (OVERSHOOT - 1.0);
    if gap < d_min {
        d_min + ((margin - 1.0) * d_min).min((d_min - gap).max(slack))
    } else {
        d_min + slack
    }
}

/// Whether a round made progress: its smallest gap `gap` exceeds the best one so far by
/// `10⁻³ d_min`, or by half of what the best still lacked of `d_min` (a gap within `10⁻³ d_min`
/// of `d_min` cannot grow by more than it lacks: the 45 % Couette shell's rounds took its gap
/// from `d_min − 6·10⁻⁴ d_min` to `− 4·10⁻⁵` and `− 5·10⁻⁶ d_min`, which the fixed
/// `10⁻³ d_min` counted as stalled).
fn progressed(gap: f64, best: f64, d_min: f64) -> bool {
    gap > best + (1e-3 * d_min).min(0.5 * (d_min - best))
}

fn dot6(a: [f64; 6], b: [f64; 6]) -> f64 {
    (0..6).map(|k| a[k] * b[k]).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::shapes;

    fn placed(mut s: shapes::Surface, r: [[f64; 3]; 3], c: [f64; 3]) -> Vec<f64> {
        s.rotate(r).unwrap();
        s.translate(c);
        s.coefs().to_vec()
    }

    /// Two overlapping unit spheres: the projection moves them apart, equally and oppositely,
    /// to at least `d_min` (exact gap `|c₁ − c₂| − 2`, which the measured gap equals), and not
    /// much further than the least move.
    #[test]
    fn overlapping_spheres_are_moved_apart() {
        let p = 6;
        let id = rotation_from_vector([0.0; 3]);
        let a = placed(shapes::sphere(p, 1.0).unwrap(), id, [0.0, 0.0, 0.0]);
        let b = placed(shapes::sphere(p, 1.0).unwrap(), id, [1.7, 0.3, 0.0]);
        let d_min = 0.05;
        let solver = ContactSolver::new(p, ContactParams::new(d_min)).unwrap();
        let out = solver.resolve(&[&a, &b], &[]).unwrap();
        assert!(out.gap_before < -0.2 && out.rounds >= 1 && out.moved == 2);
        let (mut a2, mut b2) = (a.clone(), b.clone());
        out.moves[0].apply(&mut a2);
        out.moves[1].apply(&mut b2);
        let s = 1.0 / (4.0 * std::f64::consts::PI).sqrt();
        let nc = a.len() / 3;
        let centre = |c: &[f64]| [c[0] * s, c[nc] * s, c[2 * nc] * s];
        let gap = dist(centre(&a2), centre(&b2)) - 2.0;
        assert!(gap >= d_min && gap < 2.0 * d_min, "{gap}");
        assert!(
            (out.gap_after - gap).abs() < 1e-9,
            "{} {gap}",
            out.gap_after
        );
        // Equal and opposite, along the line of centres.
        let (ta, tb) = (out.moves[0].translation, out.moves[1].translation);
        for k in 0..3 {
            assert!((ta[k] + tb[k]).abs() < 1e-9);
        }
        // Not much more than the least move: half of 2 + d_min − |c₁ − c₂| each.
        let least = 0.5 * (2.0 + d_min - (1.7f64.powi(2) + 0.3f64.powi(2)).sqrt());
        let moved = dot3(ta, ta).sqrt();
        assert!(moved >= least && moved < 1.1 * least, "{ta:?} {least}");
    }

    /// A unit sphere at the origin (order `p`) and two planes `z = const` whose gaps to it are
    /// `below` and `above` (the sphere's expansion is exact, its extent along `z` is 1).
    fn sphere_between_planes(p: usize, below: f64, above: f64) -> (Vec<f64>, [Wall; 2]) {
        let id = rotation_from_vector([0.0; 3]);
        let sphere = placed(shapes::sphere(p, 1.0).unwrap(), id, [0.0; 3]);
        (sphere, z_planes(-1.0 - below, 1.0 + above))
    }

    /// The extent along `z` from its centre of an ellipsoid of semi-axes `axes` turned by `q`:
    /// `√(zᵀ Q A² Qᵀ z)`, `A = diag(axes)` (its support function along `z`).
    fn z_extent(axes: [f64; 3], q: [[f64; 3]; 3]) -> f64 {
        (0..3)
            .map(|i| (axes[i] * q[2][i]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// The planes `z = lower` (allowed side above) and `z = upper` (allowed side below).
    fn z_planes(lower: f64, upper: f64) -> [Wall; 2] {
        [
            Wall {
                normal: [0.0, 0.0, 1.0],
                offset: lower,
            },
            Wall {
                normal: [0.0, 0.0, -1.0],
                offset: -upper,
            },
        ]
    }

    /// A unit sphere between two planes, `0.9 d_min` from the lower plane and `1.4 d_min` from the upper. A time step's
    /// projection pushes only the gap below `d_min` past it, by its deficit (to `1.1 d_min`),
    /// and keeps the met one at `(1 + SLACK) d_min`: one round, the sphere moved up by the
    /// least move (0.2 `d_min`), the upper gap left at `1.2 d_min`. With `spread` (a packing's
    /// target) the met gap asks for `1.2 d_min` too, `2.4 d_min` of room where there is
    /// `2.3`: the linearised problem has no solution, and projected Gauss–Seidel ends where
    /// its last sweep left it (here the upper gap at `1.2 d_min`, the lower at `1.1`). In a jammed suspension such
    /// compromises swung between two pairs below `d_min` until the rounds gave up
    /// (docs/hard_cases.md, the 45 % Couette shell).
    #[test]
    fn a_time_step_pushes_only_the_gaps_below_d_min_to_the_margin() {
        let p = 6;
        let d_min = 0.05;
        let (sphere, planes) = sphere_between_planes(p, 0.9 * d_min, 1.4 * d_min);
        let mut spread = ContactParams::new(d_min);
        spread.spread = true;
        let both = ContactSolver::new(p, spread)
            .unwrap()
            .resolve(&[&sphere], &planes)
            .unwrap();
        let t = both.moves[0].translation;
        assert!((t[2] - 0.2 * d_min).abs() < 1e-6 * d_min, "{t:?}");
        let out = ContactSolver::new(p, ContactParams::new(d_min))
            .unwrap()
            .resolve(&[&sphere], &planes)
            .unwrap();
        assert_eq!(out.rounds, 1);
        let t = out.moves[0].translation;
        assert!(t[0].abs() < 1e-12 && t[1].abs() < 1e-12, "{t:?}");
        assert!((t[2] - 0.2 * d_min).abs() < 1e-6 * d_min, "{t:?}");
        assert!(
            (out.gap_after - 1.1 * d_min).abs() < 1e-6 * d_min,
            "{}",
            out.gap_after
        );
    }

    /// A jam tighter than the slack: a unit sphere between two planes with `2.0005 d_min` of
    /// room, its lower gap `10⁻⁴ d_min` short of `d_min`. Asking both gaps for `d_min` plus the
    /// full slack (`10⁻³ d_min`) has no solution; the stalled rounds halve the slack until it
    /// fits, and the step ends with both gaps at least `d_min` (the 45 % Couette shell's step
    /// 462 stopped on such a pair when a stalled round had to gain `10⁻³ d_min`). The rounds
    /// that only halve what the smallest gap lacks count as progress.
    #[test]
    fn a_jam_tighter_than_the_slack_still_ends_at_d_min() {
        let p = 6;
        let d_min = 0.05;
        let (sphere, planes) = sphere_between_planes(p, 0.9999 * d_min, 1.0006 * d_min);
        let out = ContactSolver::new(p, ContactParams::new(d_min))
            .unwrap()
            .resolve(&[&sphere], &planes)
            .unwrap();
        assert!(out.gap_after >= d_min, "{out:?}");
        let t = out.moves[0].translation[2];
        let (lower, upper) = (0.9999 * d_min + t, 1.0006 * d_min - t);
        assert!(lower >= d_min && upper >= d_min, "{lower} {upper} {out:?}");
        assert!(out.rounds >= 2, "the full slack does not fit: {out:?}");
    }

    /// The stall rule: a fixed growth of `10⁻³ d_min` where the gap is far from `d_min`, half
    /// the deficit near it; the 45 % shell's step-462 rounds are progress, a round that only
    /// holds its gap (or loses) is not.
    #[test]
    fn rounds_that_halve_the_deficit_are_progress() {
        let d = 0.05;
        assert!(
            progressed(-10.0 * d, f64::NEG_INFINITY, d),
            "the first round"
        );
        assert!(progressed(-0.5 * d + 1.1e-3 * d, -0.5 * d, d));
        assert!(!progressed(-0.5 * d + 0.9e-3 * d, -0.5 * d, d));
        let steps = [d * (1.0 - 6e-4), d * (1.0 - 3.7e-5), d * (1.0 - 4.9e-6)];
        assert!(progressed(steps[1], steps[0], d) && progressed(steps[2], steps[1], d));
        assert!(!progressed(steps[0], steps[0], d) && !progressed(d * (1.0 - 4e-4), steps[0], d));
    }

    /// A wedge: a prolate ellipsoid (semi-axes 2, 0.5, 0.5) tilted by 0.3 rad between two
    /// planes that leave each of its ends `0.5 d_min` from them. No translation can lift both
    /// gaps (the planes hold `d_min` less room than the tilted body needs), so the
    /// translations-only projection gives up; with rotations it turns the body upright by the
    /// least angle, about the axis of the tilt, with no net shift. The exact gaps after the
    /// move (an ellipsoid's extent along `z` is `√(zᵀ Q A² Qᵀ z)`, `Q` its orientation,
    /// `A = diag(axes)`) are checked, not the sampled ones the projection measures.
    #[test]
    fn a_wedged_body_has_room_only_by_turning() {
        let p = 8;
        let d_min = 0.05;
        let axes = [2.0, 0.5, 0.5];
        let tilt = rotation_from_vector([0.0, 0.3, 0.0]);
        let body = placed(shapes::ellipsoid(p, axes).unwrap(), tilt, [0.0; 3]);
        let extent = |q: [[f64; 3]; 3]| z_extent(axes, q);
        let h = extent(tilt);
        let planes = z_planes(-h - 0.5 * d_min, h + 0.5 * d_min);
        let stuck = ContactSolver::new(p, ContactParams::new(d_min))
            .unwrap()
            .resolve(&[&body], &planes);
        assert!(
            matches!(stuck, Err(ContactError::Unresolved { .. })),
            "{stuck:?}"
        );
        let mut params = ContactParams::new(d_min);
        params.rotations = true;
        let out = ContactSolver::new(p, params)
            .unwrap()
            .resolve(&[&body], &planes)
            .unwrap();
        assert!(out.gap_after >= d_min, "{out:?}");
        let m = &out.moves[0];
        let q = matmul3(m.rotation, tilt);
        let shift = m.translation[2] + m.centre[2] - dot3(m.rotation[2], m.centre);
        let (low, high) = (
            h + 0.5 * d_min + shift - extent(q),
            h + 0.5 * d_min - shift - extent(q),
        );
        assert!(low >= 0.99 * d_min && high >= 0.99 * d_min, "{low} {high}");
        // Turned about y, upright by little more than it needs (extent drops by d_min/2).
        assert!(m.rotation[1][1] > 1.0 - 1e-12, "{:?}", m.rotation);
        assert!(shift.abs() < 1e-3 * d_min, "{shift}");
        assert!(h - extent(q) < 1.2 * d_min, "{} {}", h, extent(q));
    }

    /// A plane's gap is measured on the continuous surface, not at the samples alone: a prolate
    /// ellipsoid (semi-axes 2, 0.5, 0.5) turned (by the rotation vector `(0, 1.3, 0.6)`) so that
    /// its lowest point falls between its samples, above the plane `z = const` at an exact gap
    /// of `0.95 d_min` (its extent along `z` is `√(zᵀ Q A² Qᵀ z)`, as in the wedge). Its lowest
    /// sample stands `0.27 d_min` higher, above `d_min`, so the samples alone found nothing to
    /// do and left the body too close; Newton from the lowest sample finds the least
    /// height, and the body is lifted until the exact gap is `d_min`.
    #[test]
    fn a_body_tilted_towards_a_plane_is_kept_d_min_from_it_between_its_samples() {
        let p = 8;
        let d_min = 0.05;
        let axes = [2.0, 0.5, 0.5];
        let tilt = rotation_from_vector([0.0, 1.3, 0.6]);
        let body = placed(shapes::ellipsoid(p, axes).unwrap(), tilt, [0.0; 3]);
        let h = z_extent(axes, tilt);
        let floor = -h - 0.95 * d_min;
        let planes = [Wall {
            normal: [0.0, 0.0, 1.0],
            offset: floor,
        }];
        let sht = ShTransform::new(2 * p).unwrap();
        let surface = SurfaceDistance::new(p, &body, &sht).unwrap();
        let lowest = surface
            .samples()
            .iter()
            .map(|x| x[2])
            .fold(f64::INFINITY, f64::min);
        assert!(lowest - floor > 1.05 * d_min, "premise: {}", lowest - floor);
        let out = ContactSolver::new(p, ContactParams::new(d_min))
            .unwrap()
            .resolve(&[&body], &planes)
            .unwrap();
        assert!(out.rounds >= 1, "{out:?}");
        assert!(
            (out.gap_before - 0.95 * d_min).abs() < 1e-8 * d_min,
            "{out:?}"
        );
        let t = out.moves[0].translation;
        let gap = 0.95 * d_min + t[2];
        assert!(
            gap >= d_min * (1.0 - 1e-8) && gap < 1.2 * d_min,
            "{gap} {out:?}"
        );
    }

    /// With a period `P`: two unit spheres that overlap only across it (`c₂ + P` within `2` of
    /// `c₁`) are moved apart by the same least move as without one (the exact gap is
    /// `|c₁ − c₂ − P| − 2`), and the bodies that are apart in both senses stay. A period a body
    /// could meet its own image across is refused.
    #[test]
    fn periodic_images_are_kept_apart_too() {
        let p = 6;
        let id = rotation_from_vector([0.0; 3]);
        let period = [5.0, 0.0, 0.0];
        let a = placed(shapes::sphere(p, 1.0).unwrap(), id, [2.0, 0.0, 0.0]);
        let b = placed(shapes::sphere(p, 1.0).unwrap(), id, [-1.3, 0.3, 0.0]);
        let d_min = 0.05;
        let free = ContactSolver::new(p, ContactParams::new(d_min)).unwrap();
        let out = free.resolve(&[&a, &b], &[]).unwrap();
        assert_eq!(out.rounds, 0, "apart without the period");
        let mut params = ContactParams::new(d_min);
        params.period = Some(period);
        let solver = ContactSolver::new(p, params).unwrap();
        let out = solver.resolve(&[&a, &b], &[]).unwrap();
        let s = 1.0 / (4.0 * std::f64::consts::PI).sqrt();
        let nc = a.len() / 3;
        let centre = |c: &[f64]| [c[0] * s, c[nc] * s, c[2 * nc] * s];
        let add3 = |x: [f64; 3], y: [f64; 3]| std::array::from_fn(|k| x[k] + y[k]);
        let gap0 = dist(centre(&a), add3(centre(&b), period)) - 2.0;
        assert!(out.rounds >= 1 && out.moved == 2, "{out:?}");
        // (Overlapping, the deepest sample measures a little less than the centres' overlap.)
        assert!(
            gap0 < -0.25 && out.gap_before < -0.25,
            "{} {gap0}",
            out.gap_before
        );
        let (mut a2, mut b2) = (a.clone(), b.clone());
        out.moves[0].apply(&mut a2);
        out.moves[1].apply(&mut b2);
        let gap = dist(centre(&a2), add3(centre(&b2), period)) - 2.0;
        let direct = dist(centre(&a2), centre(&b2)) - 2.0;
        assert!(
            gap >= d_min && gap < 2.0 * d_min && direct > 0.5,
            "{gap} {direct}"
        );
        assert!(
            (out.gap_after - gap).abs() < 1e-9,
            "{} {gap}",
            out.gap_after
        );
        let least = 0.5 * (2.0 + d_min - (1.7f64.powi(2) + 0.3f64.powi(2)).sqrt());
        let moved = dot3(out.moves[0].translation, out.moves[0].translation).sqrt();
        assert!(moved >= least && moved < 1.1 * least, "{moved} {least}");
        // A period of 2.1 holds a unit sphere and its image 0.1 apart: refused.
        params.period = Some([2.1, 0.0, 0.0]);
        let short = ContactSolver::new(p, params).unwrap();
        assert!(matches!(
            short.resolve(&[&a], &[]),
            Err(ContactError::Period { body: 0, .. })
        ));
    }

    /// A tilted red blood cell pushed into a wall and into its neighbour comes out with every
    /// gap (measured independently on a fine grid) at least `d_min`, with rotations allowed.
    #[test]
    fn rbcs_and_a_wall_end_at_least_d_min_apart() {
        let p = 8;
        let ra = rotation_from_vector([0.4, 0.3, 0.0]);
        let rb = rotation_from_vector([-0.2, 0.9, 0.1]);
        let a = placed(shapes::rbc(p).unwrap(), ra, [0.0, 0.0, 0.0]);
        let b = placed(shapes::rbc(p).unwrap(), rb, [0.9, 0.4, 0.2]);
        let wall = Wall {
            normal: [0.0, 1.0, 0.0],
            offset: -1.2,
        };
        let d_min = 0.04;
        let mut params = ContactParams::new(d_min);
        params.rotations = true;
        let solver = ContactSolver::new(p, params).unwrap();
        let out = solver.resolve(&[&a, &b], &[wall]).unwrap();
        assert!(out.gap_before < 0.0 && out.gap_after >= d_min);
        let (mut a2, mut b2) = (a.clone(), b.clone());
        out.moves[0].apply(&mut a2);
        out.moves[1].apply(&mut b2);
        // Independent check: the order-64 samples of each against the other's closest point,
        // and every sample against the wall.
        let fine = ShTransform::new(64).unwrap();
        let sa = SurfaceDistance::new(p, &a2, &fine).unwrap();
        let sb = SurfaceDistance::new(p, &b2, &fine).unwrap();
        let mut scratch = DistanceScratch::new(p);
        let mut least = f64::INFINITY;
        for (s, o) in [(&sa, &sb), (&sb, &sa)] {
            for &x in s.samples() {
                least = least.min(o.closest(&mut scratch, x).distance);
                least = least.min(dot3(wall.normal, x) - wall.offset);
            }
        }
        // The closest pair of the continuous surfaces is measured, so no fine sample is closer.
        assert!(least >= d_min * (1.0 - 1e-9), "{least}");
        // Shapes are unchanged: a rigid move keeps every inter-sample distance.
        let sa0 = SurfaceDistance::new(p, &a, &fine).unwrap();
        let d0 = dist(sa0.samples()[5], sa0.samples()[900]);
        let d1 = dist(sa.samples()[5], sa.samples()[900]);
        assert!((d0 - d1).abs() < 1e-12);
    }

    /// Two cells of the 45 % Couette shell (docs/hard_cases.md; their coefficients in
    /// tests/data) between the shell's walls, a container sphere of radius 3.32 and a body of
    /// radius 1 about the origin: the least gap the projection measures from each wall is never
    /// above the exact one on an order-96 grid of the cell, and within that grid's resolution
    /// of it. The wedged cell at step 650: with Newton from the nearest sample alone the
    /// container's gap read 0.05005 where it is 0.04761 (a second place near the wall, measured
    /// at its samples only). Its rim against the container at step 950: with Newton from the
    /// sampled gap's local minima it read 0.05005 where it is 0.04934 (the rim's crest lies
    /// between samples, whose gap falls along the rim to another place).
    #[test]
    fn a_bent_cell_is_measured_at_its_least_gap_from_a_curved_wall() {
        for text in [
            include_str!("../../tests/data/wedged_rbc_p8.txt"),
            include_str!("../../tests/data/rimmed_rbc_p8.txt"),
        ] {
            least_wall_gaps_are_measured(&crate::vesicle::surface_distance::coefs_from_text(text));
        }
    }

    /// The check of [`a_bent_cell_is_measured_at_its_least_gap_from_a_curved_wall`] on one
    /// cell of order 8.
    fn least_wall_gaps_are_measured(coefs: &[f64]) {
        let p = 8;
        let d_min = 0.05;
        let solver = ContactSolver::new(p, ContactParams::new(d_min)).unwrap();
        let fine = SurfaceDistance::new(p, coefs, &ShTransform::new(96).unwrap()).unwrap();
        let bodies = solver.bodies(&[coefs]).unwrap();
        for (container, radius) in [(true, 3.32), (false, 1.0)] {
            let q = 16;
            let wall = FixedSurface::new(q, shapes::sphere(q, radius).unwrap().coefs(), container)
                .unwrap();
            let exact = fine
                .samples()
                .iter()
                .map(|&y| {
                    let r = dot3(y, y).sqrt();
                    if container {
                        radius - r
                    } else {
                        r - radius
                    }
                })
                .fold(f64::INFINITY, f64::min);
            let (_, least) = solver.measure(
                &bodies,
                &[],
                &[],
                std::slice::from_ref(&wall),
                3.0 * d_min,
                None,
            );
            let least = least.map_or(f64::INFINITY, |l| l.0);
            if exact < 3.0 * d_min {
                assert!(
                    least <= exact + 1e-9,
                    "{container}: {least} against {exact}"
                );
                assert!(exact - least < 1e-3, "{container}: {least} against {exact}");
            }
        }
    }

    /// Bodies already apart are not touched, and a bad `d_min` is refused.
    #[test]
    fn separated_bodies_stay_and_bad_distance_is_refused() {
        let p = 5;
        let id = rotation_from_vector([0.0; 3]);
        let a = placed(shapes::sphere(p, 1.0).unwrap(), id, [0.0; 3]);
        let b = placed(shapes::sphere(p, 1.0).unwrap(), id, [2.5, 0.0, 0.0]);
        let solver = ContactSolver::new(p, ContactParams::new(0.1)).unwrap();
        let out = solver.resolve(&[&a, &b], &[]).unwrap();
        assert_eq!((out.rounds, out.moved), (0, 0));
        assert!(out.gap_before.is_infinite());
        assert!(ContactSolver::new(p, ContactParams::new(0.0)).is_err());
        assert!(ContactSolver::new(p, ContactParams::new(f64::NAN)).is_err());
    }
}
