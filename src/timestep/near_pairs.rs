//! The near zones between cells, and the layer potentials one cell's densities induce in
//! another's near zone: the inter-cell operator that the near-implicit coupling
//! ([`super::near_implicit`]) puts inside the linear solve of a step.
//!
//! For cells `i ≠ j`, the targets of the pair `(i ← j)` are the grid points `x` of cell `i`
//! within the near zone of cell `j`: distance to `Γ_j` below `δ_j = c_near R_j / √p`, or
//! inside `Γ_j` (the zone of [`super::coupling`], where its near-singular corrections act).
//! On a density pair `(f_j, g_j)` (traction and double-layer density on cell `j`'s order-`p`
//! grid) the operator gives, at those targets,
//!
//! ```text
//!     K_ij (f_j, g_j)(x) = S_j[f_j](x) + D_j[g_j](x)
//! ```
//!
//! evaluated by [`OffSurface`] (smooth quadrature at order `6p` beyond `R_j/√p`, check points
//! and the on-surface value within it). Beside a plane wall ([`NearPairs::set_plane`]) the
//! images of cell `j`'s layers ([`super::near_images`]) act at the targets `x` of every cell
//! `i`, `j` itself included, within `r_j + δ_j` of the mirror of `j`'s centroid (`r_j` the
//! largest distance of its grid points from the centroid). Cells linked by a pair in either
//! direction form a *cluster* ([`NearZones::clusters`]), the unit of one joint solve; a cell
//! within the zone of its own image is a cluster of its own.
//!
//! A *round* cell (a sphere or nearly: every grid point within 10 % of the largest distance
//! from its centroid) that a zone reaches takes the operator at all its points, and so does
//! every cell an image's zone reaches. The operator acts on the change of the densities, and
//! on part of a surface that is a jump in the surface's velocity at the zone's edge, which an
//! inextensible sphere cannot follow (it has no shape to change, only a tension). Measured
//! (p = 8, `coupling = "near_implicit"`): a spherical vesicle 3.3 radii behind an RBC with
//! `λ = 5` in a tube (63 of its 144 points in the RBC's zone) stagnated GMRES at its first step
//! with the residual growing to 29; with its whole surface in the zone it runs (3.6 GMRES
//! iterations a step). A sphere 1.54 radii above a plane, half inside its image's zone,
//! stagnated at 0.03–0.4. Other cells keep the zone's points only: whole zones for every cell
//! cost 40 % more time on 27 RBCs at 17 % (`λ = 5`, 10 steps) for the same GMRES iterations.
//!
//! The refined smooth quadratures of [`OffSurface`] (orders up to 256, built per surface) are
//! left out, and its quadratures are coarser than the coupling's (`FAR_ORDER`): the
//! near-implicit step uses this operator on the *change* of the densities within a step
//! (`ρⁿ⁺¹ − ρ*`, see [`super::near_implicit`]), so its error multiplies an `O(Δt²)` quantity,
//! and each application stays cheap.

use std::collections::BTreeSet;
use std::sync::Mutex;

use rayon::prelude::*;

use super::near_images::NearImages;
use super::TimestepError;
use crate::vesicle::layer::LayerKernel;
use crate::vesicle::near::{NearParams, OffSurface, TargetInfo};

/// The smooth quadrature's order beyond the check points, `3p` (the evaluator's default is
/// `6p`), and the on-surface values' order, `p` (default `2p`). Measured on the 17 % RBC
/// lattice at `p = 8`, `λ = 5` (a cluster of 9 cells): the operator's values change by 0.8 %
/// of their norm and one application takes a third of the time (0.041 s against 0.124 s).
/// This operator acts on the densities' change within a step (module docs), so its error
/// multiplies an `O(Δt²)` quantity. The joint solve hands each cell's on-surface values from
/// its step's dense operators ([`OnSurface`], at the step's own order `2p`); the order `p`
/// serves matrix-free cells.
const FAR_ORDER: usize = 3;
const SELF_ORDER: usize = 1;

/// The evaluators' check points: 12 spaced `δ/10` (the single layer's of the coupling), no
/// refined quadratures. (The coupling's closer ones for the double layer, 16 spaced `0.07 δ`,
/// interpolate across the gap `[0, δ]` with a polynomial of degree 16 whose growth amplifies
/// round-off: the operator's products were additive only to 1.5e-6 of their norm, and GMRES
/// stagnated at 2e-7 on the joint system; with 12 spaced `δ/10`, to 1.3e-9.)
const EVALUATOR: NearParams = NearParams {
    near_distance: None,
    check_points: 12,
    check_spacing: 0.1,
    far_order: None,
    self_order: None,
    max_order: Some(0),
    smooth_ratio: None,
};

/// The least ratio of the smallest to the largest distance of a round cell's grid points from
/// its centroid ([`is_round`]).
const ROUND: f64 = 0.9;

/// The targets one source cell's near zone holds in the other cells.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceZone {
    /// The source cell `j` (index into the cells given to [`NearPairs::zones`]).
    pub source: usize,
    /// `(i, k)`: grid point `k` of cell `i`.
    pub targets: Vec<(usize, usize)>,
    /// Their positions.
    pub points: Vec<[f64; 3]>,
    /// Where each target lies relative to the source cell at the zones' geometry
    /// ([`OffSurface::classify`]), kept for the products (every GMRES iteration evaluates at
    /// the same targets on the same surface); empty for an image zone.
    pub infos: Vec<TargetInfo>,
}

/// The near zones of a set of cells at one geometry.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NearZones {
    /// One entry per source cell whose zone holds targets, in ascending source order.
    pub sources: Vec<SourceZone>,
    /// Beside a plane wall: one entry per source cell whose image's zone holds targets (the
    /// cell's own points included), in ascending source order.
    pub images: Vec<SourceZone>,
}

impl NearZones {
    /// Per cell of `n`, whether it is the source of a zone (its densities are evaluated).
    pub fn is_source(&self, n: usize) -> Vec<bool> {
        let mut source = vec![false; n];
        for z in &self.sources {
            if let Some(s) = source.get_mut(z.source) {
                *s = true;
            }
        }
        source
    }

    /// The pairs `(i, j)`, `i ≠ j`, with a target of `i` in the zone of `j` (or of its image).
    pub fn pairs(&self) -> BTreeSet<(usize, usize)> {
        self.sources
            .iter()
            .chain(&self.images)
            .flat_map(|z| z.targets.iter().map(move |&(i, _)| (i, z.source)))
            .filter(|(i, j)| i != j)
            .collect()
    }

    /// The clusters of `n` cells: the connected components of the pairs with two or more
    /// cells, and the cells alone in the zone of their own image, each ascending, ordered by
    /// their first cell.
    pub fn clusters(&self, n: usize) -> Vec<Vec<usize>> {
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut a: usize) -> usize {
            while parent[a] != a {
                parent[a] = parent[parent[a]];
                a = parent[a];
            }
            a
        }
        for (i, j) in self.pairs() {
            let (a, b) = (root(&mut parent, i), root(&mut parent, j));
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
        let mut groups: Vec<Vec<usize>> = vec![Vec::new(); n];
        for i in 0..n {
            let r = root(&mut parent, i);
            groups[r].push(i);
        }
        let mut own_image = vec![false; n];
        for z in &self.images {
            if z.targets.iter().any(|&(i, _)| i == z.source) {
                own_image[z.source] = true;
            }
        }
        groups
            .into_iter()
            .filter(|g| g.len() > 1 || g.first().is_some_and(|&i| own_image[i]))
            .collect()
    }

    /// The zones restricted to the cells `cells` (ascending), renumbered `0..cells.len()`.
    pub fn restricted(&self, cells: &[usize]) -> NearZones {
        let local = |c: usize| cells.binary_search(&c).ok();
        self.renumbered(local, local)
    }

    /// The zones with only the targets on the cells `keep(i)` (numbering unchanged).
    pub fn targets_on(&self, keep: impl Fn(usize) -> bool) -> NearZones {
        self.renumbered(Some, |i| keep(i).then_some(i))
    }

    /// The zones with each source cell `j` renamed `source(j)` and each target cell `i`
    /// `target(i)` (`None`: left out; a zone left without targets goes).
    fn renumbered(
        &self,
        source: impl Fn(usize) -> Option<usize>,
        target: impl Fn(usize) -> Option<usize>,
    ) -> NearZones {
        let map = |zones: &[SourceZone]| {
            zones
                .iter()
                .filter_map(|z| {
                    let source = source(z.source)?;
                    let keep: Vec<(usize, (usize, usize))> = z
                        .targets
                        .iter()
                        .enumerate()
                        .filter_map(|(m, &(i, k))| Some((m, (target(i)?, k))))
                        .collect();
                    (!keep.is_empty()).then(|| SourceZone {
                        source,
                        targets: keep.iter().map(|&(_, t)| t).collect(),
                        points: keep.iter().map(|&(m, _)| z.points[m]).collect(),
                        infos: if z.infos.is_empty() {
                            Vec::new()
                        } else {
                            keep.iter().map(|&(m, _)| z.infos[m]).collect()
                        },
                    })
                })
                .collect()
        };
        NearZones {
            sources: map(&self.sources),
            images: map(&self.images),
        }
    }
}

/// One cell as the near zones see it: its surface and grid points at the operators'
/// geometry.
pub struct ZoneCell<'a> {
    /// Order-`p` coefficients.
    pub surface: &'a [f64],
    /// Grid points (`n`).
    pub points: &'a [[f64; 3]],
    /// Centroid.
    pub centroid: [f64; 3],
    /// Largest distance of a grid point from the centroid.
    pub radius: f64,
    /// Whether the cell takes part (a cell that does not is neither source nor target).
    pub joins: bool,
}

/// A source cell's layers on its own surface, at its grid points (component-major `3n` each),
/// for the densities a [`NearPairs::apply`] is given: `S f` and, with a double layer, `D g`.
/// A cell's step holds the dense operators `S` and `D` at the same geometry (assembled at the
/// upsampled order `2p` that its own step uses), so a product costs a matrix–vector product
/// instead of the near-singular evaluator's singular quadrature at every grid point (at
/// `p = 12`, 22 % of a 27-cell lattice's step; that quadrature ran at order `p`).
#[derive(Clone, Copy, Debug)]
pub struct OnSurface<'a> {
    /// `S f` at the grid points.
    pub single: &'a [f64],
    /// `D g` at the grid points, where the cell's double layer is coupled.
    pub double: Option<&'a [f64]>,
}

/// The near-zone operator of cells of order `p`: evaluators pooled between calls.
pub struct NearPairs {
    p: usize,
    viscosity: f64,
    near_factor: f64,
    /// Evaluators, one per thread at work.
    pool: Mutex<Vec<OffSurface>>,
    /// The images in a plane wall (`None`: no plane).
    images: Option<NearImages>,
}

fn vesicle(e: crate::vesicle::VesicleError) -> TimestepError {
    TimestepError::from(e)
}

impl NearPairs {
    /// For cells of order `p` in a fluid of viscosity `μ`, near zones `δ = c_near R / √p`
    /// (`near_factor = c_near`, as [`super::coupling::CouplingParams::near_factor`]).
    pub fn new(p: usize, viscosity: f64, near_factor: f64) -> Self {
        NearPairs {
            p,
            viscosity,
            near_factor,
            pool: Mutex::new(Vec::new()),
            images: None,
        }
    }

    /// Near zones of `δ = zone · R / √p` from now on (evaluators already pooled are kept: they
    /// depend on the order alone).
    pub fn set_zone(&mut self, zone: f64) {
        self.near_factor = zone;
    }

    /// The images in the plane wall `wall` join the operator (module docs); `None`: no plane.
    pub fn set_plane(&mut self, wall: Option<crate::wall::PlaneWall>) {
        self.images = wall.map(|w| NearImages::new(w, self.viscosity, self.p));
    }

    /// Whether the images in a plane wall are part of the operator.
    pub fn has_plane(&self) -> bool {
        self.images.is_some()
    }

    /// The cells' order `p`.
    pub fn order(&self) -> usize {
        self.p
    }

    fn take(&self) -> Result<OffSurface, TimestepError> {
        let free = self.pool.lock().unwrap_or_else(|e| e.into_inner()).pop();
        match free {
            Some(o) => Ok(o),
            None => {
                let params = NearParams {
                    far_order: Some(FAR_ORDER * self.p),
                    self_order: Some(SELF_ORDER * self.p),
                    ..EVALUATOR
                };
                OffSurface::new(self.p, params).map_err(vesicle)
            }
        }
    }

    fn give(&self, o: OffSurface) {
        self.pool.lock().unwrap_or_else(|e| e.into_inner()).push(o);
    }

    /// The near zones of `cells` (see the module docs).
    pub fn zones(&self, cells: &[ZoneCell<'_>]) -> Result<NearZones, TimestepError> {
        type Found = (Option<SourceZone>, Option<SourceZone>);
        let round: Vec<bool> = cells.iter().map(is_round).collect();
        let found: Result<Vec<Found>, TimestepError> = (0..cells.len())
            .into_par_iter()
            .map(|j| {
                let cj = &cells[j];
                if !cj.joins {
                    return Ok((None, None));
                }
                let mut off = self.take()?;
                let found = (|| {
                    off.set_surface(cj.surface).map_err(vesicle)?;
                    // The evaluator's own δ is R_j / √p (its default): R_j from it.
                    let delta = self.near_factor * off.near_distance();
                    let reach = cj.radius + delta;
                    let mut targets = Vec::new();
                    let mut points = Vec::new();
                    let mut infos = Vec::new();
                    for (i, ci) in cells.iter().enumerate() {
                        if i == j || !ci.joins || dist(ci.centroid, cj.centroid) > ci.radius + reach
                        {
                            continue;
                        }
                        let before = targets.len();
                        for (k, &x) in ci.points.iter().enumerate() {
                            if dist(x, cj.centroid) > reach {
                                continue;
                            }
                            let info = off.classify(x).map_err(vesicle)?;
                            if info.inside || info.distance < delta {
                                targets.push((i, k));
                                points.push(x);
                                infos.push(info);
                            }
                        }
                        if round[i] && targets.len() > before {
                            targets.truncate(before);
                            points.truncate(before);
                            infos.truncate(before);
                            for (k, &x) in ci.points.iter().enumerate() {
                                targets.push((i, k));
                                points.push(x);
                                infos.push(off.classify(x).map_err(vesicle)?);
                            }
                        }
                    }
                    let near = (!targets.is_empty()).then_some(SourceZone {
                        source: j,
                        targets,
                        points,
                        infos,
                    });
                    Ok((near, self.image_zone(j, cells, delta)))
                })();
                self.give(off);
                found
            })
            .collect();
        let (sources, images): (Vec<_>, Vec<_>) = found?.into_iter().unzip();
        Ok(NearZones {
            sources: sources.into_iter().flatten().collect(),
            images: images.into_iter().flatten().collect(),
        })
    }

    /// The zone of cell `j`'s image in the plane (`δ` its near zone's width): the grid points
    /// of the cells, `j`'s own included, within `r_j + δ` of the mirror of its centroid.
    fn image_zone(&self, j: usize, cells: &[ZoneCell<'_>], delta: f64) -> Option<SourceZone> {
        let images = self.images.as_ref()?;
        let cj = &cells[j];
        let centre = images.mirror(cj.centroid);
        let reach = cj.radius + delta;
        let mut targets = Vec::new();
        let mut points = Vec::new();
        for (i, ci) in cells.iter().enumerate() {
            if !ci.joins || dist(ci.centroid, centre) > ci.radius + reach {
                continue;
            }
            // A cell the zone reaches takes the images at all its points: the images are
            // smooth over it, and a correction on part of a surface is a jump in its velocity
            // (measured: a sphere 1.54 radii above the plane, half inside the zone at p = 8,
            // stagnates GMRES at a residual of 0.03–0.4).
            if ci.points.iter().any(|&x| dist(x, centre) <= reach) {
                targets.extend((0..ci.points.len()).map(|k| (i, k)));
                points.extend_from_slice(ci.points);
            }
        }
        (!targets.is_empty()).then_some(SourceZone {
            source: j,
            targets,
            points,
            infos: Vec::new(),
        })
    }

    /// `out_i += Σ_j K_ij (f_j, g_j)` at the targets of `zones` (`out`: one component-major
    /// `3n` vector per cell; `surfaces[j]` the coefficients of cell `j` the zones were found
    /// at; `g_j = None`: no double layer). `on_surface[j]`, where given (the slice may be
    /// empty), holds cell `j`'s layers of these densities on its own surface, which the
    /// near-singular evaluation then takes instead of its own singular quadrature over the
    /// whole surface ([`OnSurface`]). Sums in the zones' order: deterministic.
    pub fn apply(
        &self,
        zones: &NearZones,
        surfaces: &[&[f64]],
        f: &[&[f64]],
        g: &[Option<&[f64]>],
        on_surface: &[Option<OnSurface<'_>>],
        out: &mut [Vec<f64>],
    ) -> Result<(), TimestepError> {
        let values: Result<Vec<Vec<f64>>, TimestepError> = zones
            .sources
            .par_iter()
            .map(|z| {
                let j = z.source;
                let m = z.points.len();
                let mut u = vec![0.0; 3 * m];
                let mut off = self.take()?;
                let single = LayerKernel::SingleLayer {
                    viscosity: self.viscosity,
                };
                // The zone's classification was made on this surface when the zones were
                // found; a zone built by hand (no classification) is classified here.
                let eval = |off: &mut OffSurface,
                            kernel,
                            density: &[f64],
                            given: Option<&[f64]>,
                            out: &mut [f64]| {
                    if z.infos.len() == z.points.len() {
                        off.evaluate_classified(kernel, density, given, &z.points, &z.infos, out)
                    } else if let Some(v) = given {
                        off.evaluate_given_on_surface(kernel, density, v, &z.points, out)
                    } else {
                        off.evaluate(kernel, density, &z.points, out)
                    }
                };
                let given = on_surface.get(j).and_then(|o| o.as_ref());
                let mut r = off
                    .set_surface(surfaces[j])
                    .and_then(|_| eval(&mut off, single, f[j], given.map(|o| o.single), &mut u));
                if let (Ok(_), Some(gj)) = (&r, g[j]) {
                    let mut d = vec![0.0; 3 * m];
                    let given = given.and_then(|o| o.double);
                    r = eval(&mut off, LayerKernel::DoubleLayer, gj, given, &mut d);
                    for (a, b) in u.iter_mut().zip(&d) {
                        *a += b;
                    }
                }
                self.give(off);
                r.map_err(vesicle)?;
                Ok(u)
            })
            .collect();
        scatter(&zones.sources, values?, out);
        if zones.images.is_empty() {
            return Ok(());
        }
        let Some(images) = &self.images else {
            return Err(TimestepError::Wall(
                "near zones hold a plane's images, and the operator has no plane".into(),
            ));
        };
        let values: Result<Vec<Vec<f64>>, TimestepError> = zones
            .images
            .par_iter()
            .map(|z| {
                let j = z.source;
                let mut u = vec![0.0; 3 * z.points.len()];
                images.add(surfaces[j], f[j], g[j], &z.points, &mut u)?;
                Ok(u)
            })
            .collect();
        scatter(&zones.images, values?, out);
        Ok(())
    }
}

/// `out_i += u` at the targets of `zones` (`values`: one component-major vector per zone), in
/// the zones' order.
fn scatter(zones: &[SourceZone], values: Vec<Vec<f64>>, out: &mut [Vec<f64>]) {
    for (z, u) in zones.iter().zip(values) {
        let m = z.points.len();
        for (t, &(i, k)) in z.targets.iter().enumerate() {
            let n = out[i].len() / 3;
            for c in 0..3 {
                out[i][c * n + k] += u[c * m + t];
            }
        }
    }
}

/// Whether a cell is round (a sphere or nearly): its grid points all lie within
/// [`ROUND`]` · r` and `r` of its centroid. A round cell in another cell's near zone takes the
/// zone at all its points (module docs).
fn is_round(c: &ZoneCell<'_>) -> bool {
    c.points
        .iter()
        .all(|&x| dist(x, c.centroid) >= ROUND * c.radius)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sph_harmonics::ShTransform;
    use crate::vesicle::layer::{RotationAlgorithm, SelfInteraction};
    use crate::vesicle::shapes::ellipsoid;

    fn zone(source: usize, targets: &[(usize, usize)]) -> SourceZone {
        SourceZone {
            source,
            targets: targets.to_vec(),
            points: vec![[0.0; 3]; targets.len()],
            infos: Vec::new(),
        }
    }

    #[test]
    fn clusters_are_the_connected_components_of_the_pairs() {
        // 0 ← 2, 2 ← 4 (one direction each), 1 ← 3 and 3 ← 1; 5 alone.
        let zones = NearZones {
            sources: vec![
                zone(1, &[(3, 0)]),
                zone(2, &[(0, 4), (0, 5)]),
                zone(3, &[(1, 7)]),
                zone(4, &[(2, 1)]),
            ],
            images: vec![],
        };
        assert_eq!(zones.clusters(6), vec![vec![0, 2, 4], vec![1, 3]]);
        // Beside a plane: cell 5 in the zone of its own image is a cluster alone; cell 4's
        // image reaching cell 1 joins the two clusters.
        let with_images = NearZones {
            images: vec![zone(4, &[(1, 0), (4, 2)]), zone(5, &[(5, 0)])],
            ..zones.clone()
        };
        assert_eq!(with_images.clusters(6), vec![vec![0, 1, 2, 3, 4], vec![5]]);
        // Restricted to cells 1 and 4 (renumbered 0 and 1): the image's targets follow.
        let r = with_images.restricted(&[1, 4]);
        assert_eq!(r.images, vec![zone(1, &[(0, 0), (1, 2)])]);
        assert_eq!(r.targets_on(|i| i == 1).images, vec![zone(1, &[(1, 2)])]);
        let r = zones.restricted(&[0, 2, 4]);
        assert_eq!(r.sources.len(), 2);
        assert_eq!(
            (r.sources[0].source, &r.sources[0].targets),
            (1, &vec![(0, 4), (0, 5)])
        );
        assert_eq!(
            (r.sources[1].source, &r.sources[1].targets),
            (2, &vec![(1, 1)])
        );
        assert!(NearZones::default().clusters(3).is_empty());
    }

    /// Two ellipsoids 0.1 apart: the near zones hold the facing points only, and the layer
    /// potentials there agree with the coupling's evaluator (refined quadratures up to order
    /// 256, the double layer's closer check points) to 2 % of their largest value: the cheaper
    /// quadratures of this operator, whose error multiplies the densities' change in a step.
    #[test]
    fn near_zone_values_agree_with_the_fine_evaluator() {
        let p = 8;
        let sht = ShTransform::new(p).unwrap();
        let n = sht.n_points();
        let mut a = ellipsoid(p, [1.0, 0.8, 0.6]).unwrap();
        let mut b = a.clone();
        a.translate([-1.05, 0.0, 0.0]);
        b.translate([1.05, 0.0, 0.0]);
        let surfaces = [a.coefs().to_vec(), b.coefs().to_vec()];
        let grids: Vec<Vec<[f64; 3]>> = [&a, &b]
            .iter()
            .map(|s| {
                let g = s.grid_positions(&sht).unwrap();
                (0..n).map(|k| [g[k], g[n + k], g[2 * n + k]]).collect()
            })
            .collect();
        let cells: Vec<ZoneCell<'_>> = (0..2)
            .map(|i| ZoneCell {
                surface: &surfaces[i],
                points: &grids[i],
                centroid: [if i == 0 { -1.05 } else { 1.05 }, 0.0, 0.0],
                radius: 1.0,
                joins: true,
            })
            .collect();
        let near = NearPairs::new(p, 1.3, 2.0);
        let zones = near.zones(&cells).unwrap();
        assert_eq!(zones.clusters(2), vec![vec![0, 1]]);
        // A wider zone (`set_zone`, the scene's `implicit_zone`) holds every target of this one
        // and more; set back, the same zones.
        let mut other = NearPairs::new(p, 1.3, 2.0);
        other.set_zone(4.0);
        let wide = other.zones(&cells).unwrap();
        let count = |z: &NearZones| z.sources.iter().map(|s| s.targets.len()).sum::<usize>();
        assert!(
            count(&wide) > count(&zones),
            "{} {}",
            count(&wide),
            count(&zones)
        );
        for (w, z) in wide.sources.iter().zip(&zones.sources) {
            assert!(z.targets.iter().all(|t| w.targets.contains(t)));
        }
        other.set_zone(2.0);
        assert_eq!(other.zones(&cells).unwrap().sources, zones.sources);
        for z in &zones.sources {
            assert!(z.targets.len() < n / 2, "only the facing side is near");
            for &(i, k) in &z.targets {
                assert_ne!(i, z.source);
                // Facing points: on the side of the other cell.
                let x = grids[i][k][0];
                assert!(if i == 0 { x > -1.05 } else { x < 1.05 });
            }
        }
        // Smooth densities: a traction and a double-layer density on both cells.
        let dens = |g: &[[f64; 3]], s: f64| -> Vec<f64> {
            let mut d = vec![0.0; 3 * n];
            for (k, x) in g.iter().enumerate() {
                d[k] = s * (1.0 + x[1]);
                d[n + k] = x[0] * x[2];
                d[2 * n + k] = 0.5 - s * x[1] * x[1];
            }
            d
        };
        let f = [dens(&grids[0], 1.0), dens(&grids[1], -0.5)];
        let g = [dens(&grids[0], 0.3), dens(&grids[1], 2.0)];
        let mut out = vec![vec![0.0; 3 * n]; 2];
        near.apply(
            &zones,
            &[&surfaces[0], &surfaces[1]],
            &[&f[0], &f[1]],
            &[Some(&g[0]), Some(&g[1])],
            &[],
            &mut out,
        )
        .unwrap();
        // The same with the layers on each surface given, as a step's dense operators (the
        // singular quadrature at order 2p) give them.
        let mut own = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).unwrap();
        let single = LayerKernel::SingleLayer { viscosity: 1.3 };
        let values: Vec<(Vec<f64>, Vec<f64>)> = (0..2)
            .map(|j| {
                let (mut sf, mut dg) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
                own.evaluate(single, &surfaces[j], &f[j], &mut sf).unwrap();
                own.evaluate(LayerKernel::DoubleLayer, &surfaces[j], &g[j], &mut dg)
                    .unwrap();
                (sf, dg)
            })
            .collect();
        let given: Vec<Option<OnSurface<'_>>> = values
            .iter()
            .map(|(sf, dg)| {
                Some(OnSurface {
                    single: sf,
                    double: Some(dg),
                })
            })
            .collect();
        let mut out_given = vec![vec![0.0; 3 * n]; 2];
        near.apply(
            &zones,
            &[&surfaces[0], &surfaces[1]],
            &[&f[0], &f[1]],
            &[Some(&g[0]), Some(&g[1])],
            &given,
            &mut out_given,
        )
        .unwrap();
        // The fine evaluators of the coupling.
        let mut fine_s = OffSurface::new(p, NearParams::default()).unwrap();
        let mut fine_d = OffSurface::new(
            p,
            NearParams {
                check_points: 16,
                check_spacing: 0.07,
                ..NearParams::default()
            },
        )
        .unwrap();
        let (mut worst, mut worst_given, mut scale) = (0.0f64, 0.0f64, 0.0f64);
        for z in &zones.sources {
            let j = z.source;
            let m = z.points.len();
            let (mut us, mut ud) = (vec![0.0; 3 * m], vec![0.0; 3 * m]);
            fine_s.set_surface(&surfaces[j]).unwrap();
            fine_s
                .evaluate(
                    LayerKernel::SingleLayer { viscosity: 1.3 },
                    &f[j],
                    &z.points,
                    &mut us,
                )
                .unwrap();
            fine_d.set_surface(&surfaces[j]).unwrap();
            fine_d
                .evaluate(LayerKernel::DoubleLayer, &g[j], &z.points, &mut ud)
                .unwrap();
            for (t, &(i, k)) in z.targets.iter().enumerate() {
                for c in 0..3 {
                    let want = us[c * m + t] + ud[c * m + t];
                    worst = worst.max((out[i][c * n + k] - want).abs());
                    worst_given = worst_given.max((out_given[i][c * n + k] - want).abs());
                    scale = scale.max(want.abs());
                }
            }
        }
        assert!(scale > 0.1, "the potentials are not small: {scale}");
        assert!(worst <= 0.02 * scale, "error {worst:.3e} of {scale:.3e}");
        // With the layers given (the finer quadrature of a step's operators, where the
        // evaluator's own is of order p), the values move by less than their error against the
        // fine evaluators, which the check points and the smooth quadrature set.
        let moved = out
            .iter()
            .zip(&out_given)
            .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
            .fold(0.0f64, f64::max);
        println!(
            "error {worst:.3e}, with the layers given {worst_given:.3e} (moved {moved:.3e}), \
             of {scale:.3e}"
        );
        assert!(
            moved > 0.0 && moved < 0.1 * worst,
            "{moved:.3e} against {worst:.3e}"
        );
        assert!(
            worst_given <= 1.01 * worst,
            "{worst_given:.3e} against {worst:.3e}"
        );
        // Points outside the zones get nothing.
        let inside: BTreeSet<(usize, usize)> = zones
            .sources
            .iter()
            .flat_map(|z| z.targets.iter().copied())
            .collect();
        for (i, o) in out.iter().enumerate() {
            for k in 0..n {
                if !inside.contains(&(i, k)) {
                    assert!((0..3).all(|c| o[c * n + k] == 0.0));
                }
            }
        }
    }
}
