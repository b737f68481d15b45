//! The completed double-layer system of a set of walls: assembled and factored once, solved
//! for every boundary velocity (the equations are in the [module docs](super)).

use std::f64::consts::PI;
use std::ops::Range;

use crate::lu_pivots;
use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::{Mat, MatMut};

use super::quadrature::{resolving_order, Upsampled};
use super::rows::{RowShare, WallBand, WallRows};
use super::{check_len, Wall, WallError, WallKind};
use crate::linalg3::dot3;
use crate::sph_harmonics::ShTransform;
use crate::vesicle::surface_distance::{DistanceScratch, SurfaceDistance};
use crate::vesicle::{LayerKernel, RotationAlgorithm, SelfInteraction};

/// Quadrature settings of [`WallSystem`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WallParams {
    /// Order of the singular quadrature of a wall's own block; `None` gives `2p`.
    pub self_order: Option<usize>,
    /// Largest order of the smooth quadrature between walls; `None` gives `max(128, 4p)`.
    pub max_order: Option<usize>,
    /// A pair is resolved by the order `q` when its distance is at least
    /// `resolve_ratio · 2π R_max / q` (`R_max` the source's largest radius).
    pub resolve_ratio: f64,
}

impl Default for WallParams {
    fn default() -> Self {
        WallParams {
            self_order: None,
            max_order: None,
            resolve_ratio: 2.5,
        }
    }
}

/// The largest net flux `|∫U·n dA| / ∫|U| dA` of a container's velocity that
/// [`WallSystem::solve`] accepts (sampled data of a divergence-free field carries the
/// quadrature error, 4e-7 for a Stokeslet 0.7 radii outside a sphere at p = 12).
pub const MAX_NET_FLUX: f64 = 1e-4;

/// The walls' operator, assembled once and LU-factored once; or, split over ranks, this
/// rank's rows of it ([`WallRows`]).
pub struct WallSystem {
    walls: Vec<Wall>,
    offsets: Vec<usize>,
    container: Option<usize>,
    /// Smooth-quadrature order used for each (target, source) pair, `None` on the diagonal.
    orders: Vec<Vec<Option<usize>>>,
    operator: Operator,
    pivot_ratio: f64,
}

/// The whole operator's factors, or one rank's rows.
enum Operator {
    Whole(PartialPivLu<f64>),
    Rows(WallRows),
}

/// The densities of one solve, and what they say about the bodies.
#[derive(Clone, Debug)]
pub struct WallSolution {
    densities: Vec<f64>,
    offsets: Vec<usize>,
    /// `a_k = ∫ ψ_k dA` and `b_k = ∫ (y − c_k) × ψ_k dA` per wall (zero for a container).
    moments: Vec<([f64; 3], [f64; 3])>,
    kinds: Vec<WallKind>,
    centroids: Vec<[f64; 3]>,
    /// `K_kk ψ_k` per wall where the equation gives it (one wall), see
    /// [`WallSolution::own_double_layer`].
    own: Vec<Option<Vec<f64>>>,
}

impl WallSystem {
    /// Assemble and factor the system of `walls` (at most one container; the bodies inside it
    /// and outside one another).
    ///
    /// # Errors
    /// [`WallError::Empty`], [`WallError::TwoContainers`], [`WallError::Placement`] (a body
    /// not inside the container or inside another body), [`WallError::TooClose`] (a pair the
    /// largest quadrature order does not resolve), [`WallError::Singular`].
    pub fn new(walls: Vec<Wall>, params: WallParams) -> Result<Self, WallError> {
        Self::new_share(walls, params, RowShare::WHOLE)
    }

    /// [`Self::new`] holding only the rows of `share` ([`RowShare::bands`]) and the factors of
    /// their diagonal block ([`WallRows`]); the whole system for [`RowShare::WHOLE`]. Split,
    /// the system is solved over the ranks ([`Self::rows`]), not by [`Self::solve`].
    ///
    /// # Errors
    /// As [`Self::new`] (a singular diagonal block is [`WallError::Singular`]), and
    /// [`WallError::Parameter`] for a rank outside the ranks.
    pub fn new_share(
        walls: Vec<Wall>,
        params: WallParams,
        share: RowShare,
    ) -> Result<Self, WallError> {
        if walls.is_empty() {
            return Err(WallError::Empty);
        }
        if !(params.resolve_ratio.is_finite() && params.resolve_ratio > 0.0) {
            return Err(WallError::Parameter {
                name: "resolve_ratio",
                value: params.resolve_ratio,
                reason: "must be positive and finite",
            });
        }
        if share.ranks == 0 || share.rank >= share.ranks {
            return Err(WallError::Parameter {
                name: "rank",
                value: share.rank as f64,
                reason: "must be below the number of ranks (at least one)",
            });
        }
        let mut container = None;
        for (i, w) in walls.iter().enumerate() {
            if w.kind() == WallKind::Container {
                if let Some(first) = container {
                    return Err(WallError::TwoContainers { first, second: i });
                }
                container = Some(i);
            }
        }
        let mut offsets = vec![0];
        for w in &walls {
            offsets.push(offsets.last().unwrap() + 3 * w.n_points());
        }
        let orders = pair_orders(&walls, &params)?;
        let bands = share.bands(&walls);
        let m = assemble_bands(&walls, &params, &offsets, &orders, &bands)?;
        for j in 0..m.ncols() {
            for i in 0..m.nrows() {
                if !m[(i, j)].is_finite() {
                    return Err(WallError::NonFinite {
                        what: "the wall operator",
                    });
                }
            }
        }
        let (operator, pivot_ratio, n_block) = if share.is_whole() {
            let lu = m.partial_piv_lu();
            let pivot_ratio = lu_pivots::pivot_ratio(lu.U());
            (Operator::Whole(lu), pivot_ratio, m.nrows())
        } else {
            let rows = WallRows::new(share, &walls, &offsets, m);
            let (ratio, nr) = (rows.pivot_ratio(), rows.n_rows());
            (Operator::Rows(rows), ratio, nr)
        };
        if n_block > 0 && !lu_pivots::accepts(pivot_ratio, lu_pivots::roundoff_floor(n_block)) {
            return Err(WallError::Singular { pivot_ratio });
        }
        Ok(WallSystem {
            walls,
            offsets,
            container,
            orders,
            operator,
            pivot_ratio,
        })
    }

    /// The walls.
    pub fn walls(&self) -> &[Wall] {
        &self.walls
    }
    /// Wall `i`.
    pub fn wall(&self, i: usize) -> &Wall {
        &self.walls[i]
    }
    /// Unknowns (three per grid point of every wall).
    pub fn n_unknowns(&self) -> usize {
        *self.offsets.last().unwrap()
    }
    /// The smooth-quadrature order the block of targets on wall `target` and sources on wall
    /// `source` was assembled with (`None` for `target == source`).
    pub fn quadrature_order(&self, target: usize, source: usize) -> Option<usize> {
        self.orders[target][source]
    }
    /// Smallest over largest pivot of the factorisation (a cheap conditioning indicator).
    pub fn pivot_ratio(&self) -> f64 {
        self.pivot_ratio
    }

    /// The densities for the boundary velocity `velocity` (every wall's grid velocity,
    /// component-major per wall, walls in order).
    ///
    /// # Errors
    /// [`WallError::Length`], [`WallError::NonFinite`], and [`WallError::NetFlux`] when the
    /// container's velocity carries a net flux above [`MAX_NET_FLUX`] of `∫|U| dA`. A smaller
    /// flux (the quadrature error of sampled data) is removed by the completion: the double
    /// layer then meets `U − n ∫U·n dA / A`.
    pub fn solve(&self, velocity: &[f64]) -> Result<WallSolution, WallError> {
        self.solve_formed(velocity, 0.0)
    }

    /// [`Self::solve`] for a boundary velocity formed as a sum of fields whose sizes on the
    /// container add up to `scale` (`∫ Σ|U_k| dA`): its net flux is also accepted when it is
    /// below `10⁻⁹ MAX_NET_FLUX` of `scale`, the round-off of those fields. A wall that takes
    /// the background flow's own velocity (a tube carrying Poiseuille's flow) leaves the
    /// boundary velocity `U_w − u_∞` zero up to round-off, whose net flux is not small beside
    /// itself.
    pub fn solve_formed(&self, velocity: &[f64], scale: f64) -> Result<WallSolution, WallError> {
        self.check_data(velocity, scale)?;
        let Operator::Whole(lu) = &self.operator else {
            return Err(WallError::Split);
        };
        let n = self.n_unknowns();
        let mut rhs = Mat::<f64>::zeros(n, 1);
        for (i, v) in velocity.iter().enumerate() {
            rhs[(i, 0)] = *v;
        }
        lu.solve_in_place(rhs.as_mut());
        let densities: Vec<f64> = (0..n).map(|i| rhs[(i, 0)]).collect();
        self.solution(densities, velocity)
    }

    /// This rank's rows when the system is split over ranks ([`Self::new_share`]); `None` for
    /// the whole system.
    pub fn rows(&self) -> Option<&WallRows> {
        match &self.operator {
            Operator::Whole(_) => None,
            Operator::Rows(r) => Some(r),
        }
    }

    /// The checks of [`Self::solve_formed`] on a boundary velocity, without the solve: its
    /// length, finite values and the container's net flux.
    ///
    /// # Errors
    /// As [`Self::solve_formed`].
    pub fn check_data(&self, velocity: &[f64], scale: f64) -> Result<(), WallError> {
        let n = self.n_unknowns();
        check_len("boundary velocity", velocity.len(), n)?;
        if !velocity.iter().all(|v| v.is_finite()) {
            return Err(WallError::NonFinite {
                what: "the boundary velocity",
            });
        }
        if let Some(c) = self.container {
            let w = &self.walls[c];
            let u = &velocity[self.offsets[c]..self.offsets[c + 1]];
            let (flux, size) = w.geometry().normal_flux(u);
            if flux.abs() > MAX_NET_FLUX * size.max(1e-9 * scale) {
                return Err(WallError::NetFlux {
                    flux,
                    relative: flux.abs() / size,
                });
            }
        }
        Ok(())
    }

    /// The solution with the densities `densities` (every wall's, as a solve for the boundary
    /// velocity `velocity` gives them): the bodies' moments and a lone wall's own double layer.
    /// A solve over the ranks ([`Self::rows`]) ends here.
    ///
    /// # Errors
    /// [`WallError::Length`] for densities or a velocity of the wrong length.
    pub fn solution(
        &self,
        densities: Vec<f64>,
        velocity: &[f64],
    ) -> Result<WallSolution, WallError> {
        check_len("wall densities", densities.len(), self.n_unknowns())?;
        check_len("boundary velocity", velocity.len(), self.n_unknowns())?;
        let moments = self
            .walls
            .iter()
            .enumerate()
            .map(|(k, w)| match w.kind() {
                WallKind::Container => ([0.0; 3], [0.0; 3]),
                WallKind::Body => body_moments(w, &densities[self.offsets[k]..self.offsets[k + 1]]),
            })
            .collect();
        let mut solution = WallSolution {
            densities,
            offsets: self.offsets.clone(),
            moments,
            kinds: self.walls.iter().map(|w| w.kind()).collect(),
            centroids: self.walls.iter().map(|w| w.centroid()).collect(),
            own: vec![None; self.walls.len()],
        };
        if let [w] = self.walls.as_slice() {
            solution.own[0] = Some(own_double_layer(w, velocity, &solution));
        }
        Ok(solution)
    }
}

/// `K ψ` of a lone wall at its grid points, from the equation its solve met:
/// `K ψ = U + ½ψ − n (1/A) ∫ n·ψ dA` in a container, `K ψ = U − ½ψ − (its Stokeslet and rotlet)`
/// on a body. Exact up to the solve's residual, and `O(N)` where the singular quadrature is
/// `O(N²)` with a large constant.
fn own_double_layer(w: &Wall, velocity: &[f64], solution: &WallSolution) -> Vec<f64> {
    let np = w.n_points();
    let g = w.geometry();
    let psi = solution.density(0);
    let mut v = velocity.to_vec();
    match w.kind() {
        WallKind::Container => {
            let (flux, _) = g.normal_flux(psi);
            let area = w.area();
            for j in 0..np {
                for a in 0..3 {
                    v[a * np + j] += 0.5 * psi[a * np + j] - g.normal[j][a] * flux / area;
                }
            }
        }
        WallKind::Body => {
            for (j, &x) in g.x.iter().enumerate() {
                let c = solution.completion_at(x);
                for a in 0..3 {
                    v[a * np + j] -= 0.5 * psi[a * np + j] + c[a];
                }
            }
        }
    }
    v
}

impl WallSolution {
    /// Every wall's density, walls in order (the layout of the system's unknowns).
    pub fn densities(&self) -> &[f64] {
        &self.densities
    }
    /// Wall `i`'s density `ψ_i` (component-major on its grid).
    pub fn density(&self, i: usize) -> &[f64] {
        &self.densities[self.offsets[i]..self.offsets[i + 1]]
    }
    /// The principal value of wall `i`'s own double layer, `K_ii ψ_i` at its grid points
    /// (component-major), where the solve's equation gives it without a quadrature: a system of
    /// one wall, where no other wall's layer enters. `None` otherwise.
    pub fn own_double_layer(&self, i: usize) -> Option<&[f64]> {
        self.own.get(i)?.as_deref()
    }
    /// The hydrodynamic force of the fluid (viscosity `viscosity`) on body `i`, `−μ ∫ψ_i dA`
    /// (zero for the container).
    pub fn force(&self, i: usize, viscosity: f64) -> [f64; 3] {
        self.moments[i].0.map(|v| -viscosity * v)
    }
    /// The hydrodynamic torque on body `i` about its centroid, `−μ ∫(y − c_i) × ψ_i dA`.
    pub fn torque(&self, i: usize, viscosity: f64) -> [f64; 3] {
        self.moments[i].1.map(|v| -viscosity * v)
    }
    /// `(a_i, b_i)`, the strengths of body `i`'s Stokeslet and rotlet (zero for a container).
    pub fn moments(&self, i: usize) -> ([f64; 3], [f64; 3]) {
        self.moments[i]
    }
    /// The completion velocity of every body at `x`:
    /// `Σ_k (1/8π) [G(x − c_k) a_k + b_k × r / r³]`.
    pub fn completion_at(&self, x: [f64; 3]) -> [f64; 3] {
        let mut u = [0.0; 3];
        for ((kind, c), (a, b)) in self.kinds.iter().zip(&self.centroids).zip(&self.moments) {
            if *kind != WallKind::Body {
                continue;
            }
            let r = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
            let r2 = dot3(r, r);
            let ri = 1.0 / r2.sqrt();
            let ri3 = ri / r2;
            let ra = dot3(r, *a);
            let bxr = crate::linalg3::cross3(*b, r);
            for d in 0..3 {
                u[d] += (a[d] * ri + r[d] * ra * ri3 + bxr[d] * ri3) / (8.0 * PI);
            }
        }
        u
    }
}

/// `(∫ψ dA, ∫(y − c) × ψ dA)` over a wall.
fn body_moments(w: &Wall, psi: &[f64]) -> ([f64; 3], [f64; 3]) {
    let np = w.n_points();
    let g = w.geometry();
    let c = w.centroid();
    let (mut a, mut b) = ([0.0; 3], [0.0; 3]);
    for j in 0..np {
        let f = [psi[j], psi[np + j], psi[2 * np + j]];
        let s = [g.x[j][0] - c[0], g.x[j][1] - c[1], g.x[j][2] - c[2]];
        let sxf = crate::linalg3::cross3(s, f);
        for d in 0..3 {
            a[d] += g.da[j] * f[d];
            b[d] += g.da[j] * sxf[d];
        }
    }
    (a, b)
}

/// The order of every off-diagonal block from the true distances between the walls, checking
/// on the way that every wall's points are on the fluid side of every other wall.
fn pair_orders(walls: &[Wall], params: &WallParams) -> Result<Vec<Vec<Option<usize>>>, WallError> {
    let nw = walls.len();
    let mut orders = vec![vec![None; nw]; nw];
    for (s, src) in walls.iter().enumerate() {
        let p = src.order();
        let max_order = params.max_order.unwrap_or(128.max(4 * p));
        let dist = SurfaceDistance::new(p, src.surface().coefs(), &ShTransform::new(2 * p)?)?;
        let mut scratch = DistanceScratch::new(p);
        for (t, tgt) in walls.iter().enumerate() {
            if t == s {
                continue;
            }
            let mut least = f64::INFINITY;
            for &x in &tgt.geometry().x {
                let d = dist.closest(&mut scratch, x).distance;
                let wrong_side = match src.kind() {
                    WallKind::Body => d <= 0.0,
                    WallKind::Container => d >= 0.0,
                };
                if wrong_side {
                    return Err(WallError::Placement {
                        index: t,
                        reason: match src.kind() {
                            WallKind::Body => "it reaches inside a body",
                            WallKind::Container => "it reaches outside the container",
                        },
                    });
                }
                least = least.min(d.abs());
            }
            orders[t][s] = Some(
                resolving_order(p, src.max_radius(), least, params.resolve_ratio, max_order)
                    .ok_or(WallError::TooClose {
                        target: t,
                        from: s,
                        distance: least,
                        order: max_order,
                        needed: params.resolve_ratio * 2.0 * PI * src.max_radius()
                            / max_order as f64,
                    })?,
            );
        }
    }
    Ok(orders)
}

/// The rows of the bands `bands` of the walls' system (`Σ 3k_b × n`, band by band, each band's
/// points component by component: [`RowShare::unknowns`]): every wall's own block, the double
/// layers between walls and the bodies' completions at the bands' points. For the whole system
/// (every wall one band) this is the system itself.
fn assemble_bands(
    walls: &[Wall],
    params: &WallParams,
    offsets: &[usize],
    orders: &[Vec<Option<usize>>],
    bands: &[WallBand],
) -> Result<Mat<f64>, WallError> {
    let n = *offsets.last().expect("offsets start at 0");
    let firsts: Vec<usize> = bands
        .iter()
        .scan(0, |row, b| {
            let first = *row;
            *row += 3 * b.points(walls).len();
            Some(first)
        })
        .collect();
    let nr: usize = bands.iter().map(|b| 3 * b.points(walls).len()).sum();
    let mut m = Mat::<f64>::zeros(nr, n);
    for (b, &r0) in bands.iter().zip(&firsts) {
        let w = &walls[b.wall];
        let k3 = 3 * b.points(walls).len();
        let np3 = 3 * w.n_points();
        add_self_rows(
            w,
            params,
            b.lats.clone(),
            m.as_mut().submatrix_mut(r0, offsets[b.wall], k3, np3),
        )?;
    }
    for (s, src) in walls.iter().enumerate() {
        let mut cache: Option<Upsampled> = None;
        for (b, &r0) in bands.iter().zip(&firsts) {
            let Some(q) = orders[b.wall][s] else { continue };
            if cache.as_ref().map(|u| u.order()) != Some(q) {
                cache = Some(Upsampled::new(src, q)?);
            }
            let up = cache.as_ref().expect("built above");
            let x = &walls[b.wall].geometry().x[b.points(walls)];
            up.double_layer_block(
                x,
                m.as_mut()
                    .submatrix_mut(r0, offsets[s], 3 * x.len(), 3 * src.n_points()),
            );
        }
    }
    for (k, w) in walls.iter().enumerate() {
        if w.kind() == WallKind::Body {
            for (b, &r0) in bands.iter().zip(&firsts) {
                let x = &walls[b.wall].geometry().x[b.points(walls)];
                add_body_completion(
                    w,
                    x,
                    m.as_mut()
                        .submatrix_mut(r0, offsets[k], 3 * x.len(), 3 * w.n_points()),
                );
            }
        }
    }
    Ok(m)
}

/// The rows of wall `w`'s own block at the points of its latitudes `lats`: `K_kk ∓ ½ I` (the
/// fluid's side) and, for a container, `n (1/A) ∫ n·ψ dA` (rows `a·k + (t − t₀)` over the
/// band's `k` points from `t₀`).
fn add_self_rows(
    w: &Wall,
    params: &WallParams,
    lats: Range<usize>,
    mut out: MatMut<'_, f64>,
) -> Result<(), WallError> {
    let p = w.order();
    let np = w.n_points();
    let (t0, k) = (2 * p * lats.start, 2 * p * lats.len());
    let mut si = SelfInteraction::new(
        p,
        params.self_order.unwrap_or(2 * p),
        RotationAlgorithm::ViaSh,
    )?;
    si.assemble_latitudes(
        LayerKernel::DoubleLayer,
        w.surface().coefs(),
        lats,
        out.as_mut(),
    )?;
    let jump = match w.kind() {
        WallKind::Container => -0.5,
        WallKind::Body => 0.5,
    };
    for a in 0..3 {
        for t in 0..k {
            out[(a * k + t, a * np + t0 + t)] += jump;
        }
    }
    if w.kind() == WallKind::Container {
        let g = w.geometry();
        let area = w.area();
        for b in 0..3 {
            for j in 0..np {
                let wj = g.normal[j][b] * g.da[j] / area;
                for a in 0..3 {
                    for t in 0..k {
                        out[(a * k + t, b * np + j)] += g.normal[t0 + t][a] * wj;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Body `w`'s Stokeslet and rotlet at the points `targets`, as columns over `w`'s density:
/// `∂u_a(x_t)/∂ψ_b(y_j) = dA_j/8π [G_ab(r) + δ_ab (s·r)/r³ − s_a r_b/r³]`, `r = x_t − c`,
/// `s = y_j − c` (from `(s × e_b) × r = e_b (s·r) − s r_b`).
fn add_body_completion(w: &Wall, targets: &[[f64; 3]], mut out: MatMut<'_, f64>) {
    let g = w.geometry();
    let c = w.centroid();
    let (np, nt) = (w.n_points(), targets.len());
    for (t, &x) in targets.iter().enumerate() {
        let r = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
        let r2 = dot3(r, r);
        let ri = 1.0 / r2.sqrt();
        let ri3 = ri / r2;
        for j in 0..np {
            let s = [g.x[j][0] - c[0], g.x[j][1] - c[1], g.x[j][2] - c[2]];
            let sr = dot3(s, r);
            let wt = g.da[j] / (8.0 * PI);
            for a in 0..3 {
                for b in 0..3 {
                    let delta = if a == b { ri + sr * ri3 } else { 0.0 };
                    let v = delta + r[a] * r[b] * ri3 - s[a] * r[b] * ri3;
                    out[(a * nt + t, b * np + j)] += wt * v;
                }
            }
        }
    }
}
