//! The near-implicit step over MPI ranks ([`step_all_on`]): the same clusters and the same
//! joint systems as on one rank, each rank holding the rows of its own cells.
//!
//! * **Zones and clusters.** Every rank gathers every cell's operator surface `X*`, grid points,
//!   centroid and radius (one all-gather of `3n_c + 3n + 10` words a cell) and finds the near
//!   zones of all cells in global order, as one rank does; so the clusters, and which cells step
//!   alone, are those of one rank. (This part is `O(N)` per rank, like the contact projection's
//!   gather; the ghost exchange of the explicit coupling would bound it by the neighbours.)
//! * **A cluster on one rank** is stepped there by [`step_cluster`], unchanged.
//! * **A cluster across ranks** is one GMRES over all ranks: each rank applies the step operator
//!   and the preconditioner block of its own cells, and the near-zone operator at its own
//!   targets. A product all-gathers the members' densities `ρⱼ(zⱼ)` (traction and double-layer
//!   density, `6n + 2` words a member) so that each rank has its ghost sources'. The inner products
//!   are summed over ranks in rank order ([`RankSums`]): every rank gets the same numbers and runs
//!   the same Arnoldi recurrence, ranks without a member of the cluster with empty rows.
//!
//! The iterates differ from one rank's only by the order of the inner products' sums
//! (round-off). Every phase that can fail on one rank ends with an agreement, so that all ranks
//! leave the step together ([`RanksStep`]).

use super::*;
use crate::comm::{CommError, Communicator};
use crate::timestep::gmres::{gmres_with, GmresOperator, GmresParams};
use crate::timestep::rank_sums::RankSums;

/// What the step over ranks came to on this rank.
pub(in crate::timestep) enum RanksStep {
    /// Every cell here stepped (reports in the order of the cells given), with the step's
    /// statistics over all ranks.
    Done(Vec<StepReport>, JointStats),
    /// A failure here: the cell (its index among the cells given), or `None` for a joint
    /// solve's or the exchange's.
    Failed(Option<usize>, TimestepError),
    /// Another rank failed; the cells here may be part-stepped (as on one rank, where the
    /// clusters before a failing one have stepped).
    Elsewhere,
}

type Local<T> = Result<T, (Option<usize>, TimestepError)>;

/// Every member's traction and double-layer density (`None`: none), in cluster order.
/// Every member's densities `(f, g)` and its [`LayerValues`] (where its rank holds them).
type Densities = (Vec<Vec<f64>>, Vec<Option<Vec<f64>>>, Vec<LayerValues>);

/// `local` where no rank failed; otherwise what this rank reports (collective).
fn settle<T>(comm: &dyn Communicator, local: Local<T>) -> Result<T, RanksStep> {
    let flag = u64::from(local.is_err());
    let any = match comm.all_gather_u64(&[flag]) {
        Ok(all) => all.iter().any(|v| v.first() == Some(&1)),
        Err(c) => return Err(RanksStep::Failed(None, TimestepError::Comm(c))),
    };
    match (local, any) {
        (Ok(v), false) => Ok(v),
        (Err((k, e)), _) => Err(RanksStep::Failed(k, e)),
        (Ok(_), true) => Err(RanksStep::Elsewhere),
    }
}

/// Words before the surface in a gathered cell record: id, joins, centroid, radius and the
/// cell's GMRES parameters.
const HEAD: usize = 10;

/// One cell as every rank sees it.
struct Gathered {
    id: usize,
    owner: usize,
    joins: bool,
    centroid: [f64; 3],
    radius: f64,
    gmres: GmresParams,
    /// `X*` (order-`p` coefficients).
    surface: Vec<f64>,
    points: Vec<[f64; 3]>,
}

/// [`step_all`] over the ranks of `comm` (collective; `ids` the global indices of `cells`,
/// ascending). On one rank it is [`step_all`].
pub(in crate::timestep) fn step_all_on(
    comm: &dyn Communicator,
    ids: &[usize],
    cells: &mut [JointCell<'_>],
    near: &NearPairs,
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    with_dl: bool,
) -> RanksStep {
    if comm.size() == 1 {
        return match step_all(cells, near, u_inf, with_dl) {
            Ok((reports, stats)) => RanksStep::Done(reports, stats),
            Err((k, e)) => RanksStep::Failed(k, e),
        };
    }
    match step_over_ranks(comm, ids, cells, near, u_inf, with_dl) {
        Ok((reports, stats)) => RanksStep::Done(reports, stats),
        Err(r) => r,
    }
}

fn step_over_ranks(
    comm: &dyn Communicator,
    ids: &[usize],
    cells: &mut [JointCell<'_>],
    near: &NearPairs,
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    with_dl: bool,
) -> Result<(Vec<StepReport>, JointStats), RanksStep> {
    let me = comm.rank();
    // The members of a cluster below are taken in local order and placed in cluster order:
    // the same order because both ascend with the global index.
    debug_assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids ascend");
    let global = settle(comm, gather_cells(comm, ids, cells, near))?;
    let zone_cells: Vec<ZoneCell<'_>> = global
        .iter()
        .map(|c| ZoneCell {
            surface: &c.surface,
            points: &c.points,
            centroid: c.centroid,
            radius: c.radius,
            joins: c.joins,
        })
        .collect();
    let zones = settle(comm, near.zones(&zone_cells).map_err(|e| (None, e)))?;
    drop(zone_cells);
    let clusters = zones.clusters(global.len());
    let mut cluster_of = vec![None; global.len()];
    for (ci, cl) in clusters.iter().enumerate() {
        for &g in cl {
            cluster_of[g] = Some(ci);
        }
    }
    // Where each of this rank's cells is in the global order.
    let global_of: Vec<usize> = ids
        .iter()
        .map(|id| {
            global
                .binary_search_by_key(id, |c| c.id)
                .expect("every local cell was gathered")
        })
        .collect();
    let mut local_of = vec![None; global.len()];
    for (k, &g) in global_of.iter().enumerate() {
        local_of[g] = Some(k);
    }
    let on_one_rank = |cl: &[usize]| cl.iter().all(|&g| global[g].owner == global[cl[0]].owner);

    // The cells alone and the clusters held here whole: as on one rank.
    let mut reports: Vec<Option<StepReport>> = vec![None; cells.len()];
    let mut here = JointStats::default();
    let local: Local<()> = (|| {
        step_alone(
            cells,
            |k| cluster_of[global_of[k]].is_none(),
            u_inf,
            &mut reports,
        )?;
        for cl in &clusters {
            if !(on_one_rank(cl) && global[cl[0]].owner == me) {
                continue;
            }
            let members_local: Vec<usize> = cl
                .iter()
                .map(|&g| local_of[g].expect("held here"))
                .collect();
            let held = HeldCluster {
                members: &members_local,
                zones: &zones.restricted(cl),
            };
            held.step(cells, near, u_inf, with_dl, &mut here, &mut reports)?;
        }
        Ok(())
    })();
    settle(comm, local)?;
    let mut stats = sum_stats(comm, here)?;

    // The clusters across ranks, one joint solve over all ranks each, in order.
    for cl in clusters.iter().filter(|cl| !on_one_rank(cl)) {
        let positions: Vec<(usize, usize)> = cl
            .iter()
            .enumerate()
            .filter_map(|(pos, &g)| local_of[g].map(|k| (pos, k)))
            .collect();
        let mut members: Vec<&mut JointCell<'_>> = cells
            .iter_mut()
            .enumerate()
            .filter(|(k, _)| positions.iter().any(|&(_, l)| l == *k))
            .map(|(_, c)| c)
            .collect();
        let surfaces: Vec<&[f64]> = cl.iter().map(|&g| global[g].surface.as_slice()).collect();
        let is_local: Vec<bool> = cl.iter().map(|&g| local_of[g].is_some()).collect();
        let zones_here = zones.restricted(cl).targets_on(|i| is_local[i]);
        let solve = ClusterOverRanks {
            comm,
            near,
            zones: &zones_here,
            surfaces: &surfaces,
            positions: positions.iter().map(|&(pos, _)| pos).collect(),
            params: global[cl[0]].gmres,
        };
        let (done, iterations) = solve
            .step(&mut members, u_inf, with_dl)
            .map_err(|r| match r {
                RanksStep::Failed(Some(m), e) => RanksStep::Failed(Some(positions[m].1), e),
                other => other,
            })?;
        stats.add_cluster(cl.len(), iterations);
        for (&(_, k), r) in positions.iter().zip(done) {
            reports[k] = Some(r);
        }
    }
    // Every local cell is in exactly one cluster of the agreed list; a cell left without a
    // report means the ranks' cluster lists differ (a bug, reported rather than hung on).
    match reports.iter().position(Option::is_none) {
        None => Ok((reports.into_iter().flatten().collect(), stats)),
        Some(k) => Err(RanksStep::Failed(
            Some(k),
            TimestepError::Comm(CommError::Disagree(format!(
                "near-implicit step: local cell {k} is in no cluster this rank stepped"
            ))),
        )),
    }
}

/// Every rank's cells at the operators' geometry, in global order (collective).
fn gather_cells(
    comm: &dyn Communicator,
    ids: &[usize],
    cells: &[JointCell<'_>],
    near: &NearPairs,
) -> Local<Vec<Gathered>> {
    let p = near.order();
    let (ncoef, n) = (3 * ((p + 1) * (p + 1) - 1), 2 * p * (p + 1));
    let record = HEAD + ncoef + 3 * n;
    // A failure here still takes part in the gather (with no records), so that every rank
    // makes the same collectives; the caller's `settle` then stops all.
    let local = records(ids, cells, ncoef, n);
    let all = comm
        .all_gather_f64(local.as_deref().unwrap_or(&[]))
        .map_err(|c| (None, TimestepError::Comm(c)))?;
    local?;
    let mut global = Vec::new();
    for (owner, buf) in all.iter().enumerate() {
        if buf.len() % record != 0 {
            return Err((
                None,
                TimestepError::Comm(CommError::Ranks {
                    what: "near-implicit cell records received",
                    got: buf.len(),
                    ranks: owner,
                }),
            ));
        }
        for r in buf.chunks_exact(record) {
            global.push(Gathered {
                id: r[0] as usize,
                owner,
                joins: r[1] != 0.0,
                centroid: [r[2], r[3], r[4]],
                radius: r[5],
                gmres: GmresParams {
                    tol: r[6],
                    restart: r[7] as usize,
                    max_iters: r[8] as usize,
                    min_cycle_reduction: r[9],
                },
                surface: r[HEAD..HEAD + ncoef].to_vec(),
                points: r[HEAD + ncoef..]
                    .chunks_exact(3)
                    .map(|x| [x[0], x[1], x[2]])
                    .collect(),
            });
        }
    }
    global.sort_by_key(|c| c.id);
    Ok(global)
}

/// This rank's cell records for [`gather_cells`] (`HEAD + ncoef + 3n` words a cell).
fn records(ids: &[usize], cells: &[JointCell<'_>], ncoef: usize, n: usize) -> Local<Vec<f64>> {
    let mut mine = Vec::with_capacity((HEAD + ncoef + 3 * n) * cells.len());
    for (k, (c, &id)) in cells.iter().zip(ids).enumerate() {
        let Placed {
            surface: xs,
            points,
            centroid,
            radius,
        } = place(c).map_err(|e| (Some(k), e))?;
        if xs.len() != ncoef || points.len() != n {
            return Err((
                Some(k),
                TimestepError::InvalidParameter {
                    name: "order",
                    value: format!("{} grid points", c.stepper.n_points()),
                    reason: "the near-implicit coupling over ranks needs one order for all cells",
                },
            ));
        }
        let g = c.stepper.params().gmres;
        mine.extend([id as f64, f64::from(u8::from(c.stepper.joins_near_solve()))]);
        mine.extend(centroid);
        mine.extend([
            radius,
            g.tol,
            g.restart as f64,
            g.max_iters as f64,
            g.min_cycle_reduction,
        ]);
        mine.extend_from_slice(&xs);
        mine.extend(points.iter().flatten());
    }
    Ok(mine)
}

/// The statistics of the clusters each rank solved alone, summed over ranks (collective).
fn sum_stats(comm: &dyn Communicator, here: JointStats) -> Result<JointStats, RanksStep> {
    let mine = [
        here.clusters as u64,
        here.cells as u64,
        here.largest as u64,
        here.iterations as u64,
    ];
    let all = comm
        .all_gather_u64(&mine)
        .map_err(|c| RanksStep::Failed(None, TimestepError::Comm(c)))?;
    let mut s = JointStats::default();
    for r in all.iter().filter(|r| r.len() == 4) {
        s.merge(&JointStats {
            clusters: r[0] as usize,
            cells: r[1] as usize,
            largest: r[2] as usize,
            iterations: r[3] as usize,
        });
    }
    Ok(s)
}

/// One cluster across ranks, as this rank takes part in its joint step.
struct ClusterOverRanks<'a> {
    comm: &'a dyn Communicator,
    near: &'a NearPairs,
    /// The cluster's zones (renumbered to it) with this rank's targets only.
    zones: &'a NearZones,
    /// Every member's `X*`, in cluster order.
    surfaces: &'a [&'a [f64]],
    /// The place in the cluster of each member held here (ascending).
    positions: Vec<usize>,
    /// The first member's GMRES parameters (as on one rank).
    params: GmresParams,
}

impl ClusterOverRanks<'_> {
    /// The joint step of this rank's members (collective): their reports and the solve's
    /// iterations. A member's failure names its index in `members`.
    fn step(
        &self,
        members: &mut [&mut JointCell<'_>],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        with_dl: bool,
    ) -> Result<(Vec<StepReport>, usize), RanksStep> {
        let omegas: Vec<Option<f64>> = members
            .iter()
            .map(|c| c.stepper.extrapolation_ratio(c.state))
            .collect();
        let (steps, failed) = begin_all(members, u_inf);
        if let Err(r) = settle(self.comm, failed.map_or(Ok(()), Err)) {
            abort_all(members, steps);
            return Err(r);
        }
        let steps: Vec<JointStep> = steps.into_iter().flatten().collect();
        let solved = self.solve(members, &steps, &omegas, with_dl);
        let (z, report) = match settle(self.comm, solved.map_err(|e| (None, e))) {
            Ok(r) => r,
            Err(r) => {
                abort_all(members, steps.into_iter().map(Some).collect());
                return Err(r);
            }
        };
        let ended = end_all(members, steps, &z, &report);
        Ok((settle(self.comm, ended)?, report.iterations))
    }

    /// Every member's densities `f`, `g` and layers on its own surface (`S f`, `D g`) from
    /// the ranks that hold them (`f`, `g` and `ops` for the members held here, in cluster
    /// order; collective): `g` where given, `3n` each; members held elsewhere without a double
    /// layer get `None`, and without dense layers no values.
    fn gather_densities(
        &self,
        ops: &[InextensibleOperator<'_>],
        f: &[Vec<f64>],
        g: &[Option<Vec<f64>>],
        n3: usize,
    ) -> Result<Densities, TimestepError> {
        let source = self.zones.is_source(self.surfaces.len());
        let wanted: Vec<bool> = self.positions.iter().map(|&pos| source[pos]).collect();
        let values = layer_values(ops, &wanted, f, g)?;
        let record = 4 + 4 * n3;
        let zeros = || std::iter::repeat_n(0.0, n3);
        let mut mine = Vec::with_capacity(record * f.len());
        for (((&pos, fk), gk), vk) in self.positions.iter().zip(f).zip(g).zip(&values) {
            let (sf, dg) = match vk {
                Some((sf, dg)) => (Some(sf), dg.as_ref()),
                None => (None, None),
            };
            let flag = |b: bool| f64::from(u8::from(b));
            mine.extend([
                pos as f64,
                flag(gk.is_some()),
                flag(sf.is_some()),
                flag(dg.is_some()),
            ]);
            mine.extend_from_slice(fk);
            for part in [gk.as_ref(), sf, dg] {
                match part {
                    Some(v) => mine.extend_from_slice(v),
                    None => mine.extend(zeros()),
                }
            }
        }
        let all = self
            .comm
            .all_gather_f64(&mine)
            .map_err(TimestepError::Comm)?;
        let m = self.surfaces.len();
        let mut fa = vec![Vec::new(); m];
        let mut ga = vec![None; m];
        let mut va = vec![None; m];
        for (r, buf) in all.iter().enumerate() {
            if buf.len() % record != 0 {
                return Err(TimestepError::Comm(CommError::Ranks {
                    what: "near-implicit densities received",
                    got: buf.len(),
                    ranks: r,
                }));
            }
            for rec in buf.chunks_exact(record) {
                let pos = rec[0] as usize;
                let part = |i: usize| rec[4 + i * n3..4 + (i + 1) * n3].to_vec();
                fa[pos] = part(0);
                ga[pos] = (rec[1] != 0.0).then(|| part(1));
                va[pos] = (rec[2] != 0.0).then(|| (part(2), (rec[3] != 0.0).then(|| part(3))));
            }
        }
        Ok((fa, ga, va))
    }

    /// `out_i = Σ_j K_ij (f_j, g_j)` at this rank's targets (`out`: `3n` for the members held
    /// here, in cluster order; empty elsewhere), after gathering every member's densities and
    /// layers on its own surface.
    fn near_field(
        &self,
        ops: &[InextensibleOperator<'_>],
        f: &[Vec<f64>],
        g: &[Option<Vec<f64>>],
        n3: usize,
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let (fa, ga, va) = self.gather_densities(ops, f, g, n3)?;
        let fref: Vec<&[f64]> = fa.iter().map(|v| v.as_slice()).collect();
        let gref: Vec<Option<&[f64]>> = ga.iter().map(|v| v.as_deref()).collect();
        let on: Vec<Option<OnSurface<'_>>> = va.iter().map(on_surface).collect();
        let mut w = vec![Vec::new(); self.surfaces.len()];
        for &pos in &self.positions {
            w[pos] = vec![0.0; n3];
        }
        self.near
            .apply(self.zones, self.surfaces, &fref, &gref, &on, &mut w)?;
        Ok(w)
    }

    /// [`solve_joint`] with this rank's rows (collective).
    fn solve(
        &self,
        cells: &[&mut JointCell<'_>],
        steps: &[JointStep],
        omegas: &[Option<f64>],
        with_dl: bool,
    ) -> Result<(Vec<f64>, GmresReport), TimestepError> {
        let m = cells.len();
        let p = self.near.order();
        let n = 2 * p * (p + 1);
        let (n3, n4) = (3 * n, 4 * n);
        let (tau, dl) = joint_factors(steps, with_dl);
        let (fc, gc) = constant_densities(cells, steps, omegas, &dl, n3);
        let ops = joint_operators(cells, steps);
        // A failure of the near field here still enters GMRES, with a NaN right-hand side:
        // every rank leaves it at the same collective (the finiteness check of `b`).
        let (w, near_failure) = match self.near_field(&ops, &fc, &gc, n3) {
            Ok(w) => (w, None),
            Err(e) => (vec![vec![f64::NAN; n3]; self.surfaces.len()], Some(e)),
        };
        let (b, z0) = rhs_and_guess(cells, steps, &tau, |k| &w[self.positions[k]]);
        let op = RanksOperator {
            cluster: self,
            n,
            ops,
            tau,
            dl,
            failure: Mutex::new(None),
        };
        let pc = ClusterPreconditioner::of(cells, steps, n);
        let sums = RankSums::new(self.comm);
        let mut ws = GmresWorkspace::new(n4 * m, self.params.restart);
        let mut z = vec![0.0; n4 * m];
        let report = gmres_with(
            &op,
            &pc,
            &b,
            Some(&z0),
            &mut z,
            &self.params,
            &mut ws,
            &sums,
        );
        if let Some(e) = near_failure {
            return Err(e);
        }
        if let Some(e) = sums.failure() {
            return Err(TimestepError::Comm(e));
        }
        operator_failure(op.failure, &op.ops)?;
        Ok((z, report?))
    }
}

/// The joint operator of a cluster across ranks, on this rank's rows: every member's own
/// step operator, minus `τ` times the near-zone operator of all members' densities at this
/// rank's targets (a product gathers the densities; collective).
struct RanksOperator<'a> {
    cluster: &'a ClusterOverRanks<'a>,
    n: usize,
    ops: Vec<InextensibleOperator<'a>>,
    tau: Vec<f64>,
    dl: Vec<Option<f64>>,
    failure: Mutex<Option<TimestepError>>,
}

impl GmresOperator for RanksOperator<'_> {
    fn nrows(&self) -> usize {
        4 * self.n * self.ops.len()
    }

    fn ncols(&self) -> usize {
        self.nrows()
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        let (n3, n4) = (3 * self.n, 4 * self.n);
        let (f, g) = own_products(&self.ops, &self.dl, self.n, x, y);
        // Every rank gathers, whatever failed here: the others wait for this rank's part.
        match self.cluster.near_field(&self.ops, &f, &g, n3) {
            Ok(w) => {
                for (k, &pos) in self.cluster.positions.iter().enumerate() {
                    for (yi, wi) in y[k * n4..k * n4 + n3].iter_mut().zip(&w[pos]) {
                        *yi -= self.tau[k] * wi;
                    }
                }
            }
            Err(e) => {
                let mut slot = self.failure.lock().unwrap_or_else(|e| e.into_inner());
                slot.get_or_insert(e);
                y.fill(f64::NAN);
            }
        }
    }
}
