//! The walls' system solved over MPI ranks, each rank holding its rows ([`crate::wall::WallRows`]).
//!
//! GMRES on `A M⁻¹ y = U`, `ψ = M⁻¹ y`, with `M` the block Jacobi of the ranks' diagonal blocks.
//! Each rank holds its rows of every Krylov vector; a product gathers the preconditioned vector
//! whole (`3N_wall` values, one all-gather) and multiplies the rank's rows; the inner products
//! are summed over the ranks in rank order (`RankSums`), so every rank runs the same
//! recurrence. The densities are gathered whole at the end, and every rank evaluates them at its
//! own cells as with a replicated system. The iterate meets [`WALL_ROWS_TOL`], so the answer is
//! one rank's (a direct solve) to about that relative size.

use std::sync::Mutex;

use super::gmres::{gmres_with, GmresOperator, GmresParams, GmresWorkspace};
use super::operator::Preconditioner;
use super::rank_sums::RankSums;
use super::TimestepError;
use crate::comm::{CommError, Communicator};
use crate::wall::{WallRows, WallSolution, WallSystem};

/// Relative residual the split wall solve meets (`‖U − Aψ‖ ≤ tol ‖U‖`).
pub const WALL_ROWS_TOL: f64 = 1e-13;

/// The whole vector from every rank's rows `x` of it (collective).
fn gather_whole(
    comm: &dyn Communicator,
    rows: &WallRows,
    x: &[f64],
) -> Result<Vec<f64>, TimestepError> {
    let parts = comm.all_gather_f64(x).map_err(TimestepError::Comm)?;
    Ok(rows.gather(&parts)?)
}

/// `A_r` times the whole vector gathered from every rank's rows (collective).
struct RowsOperator<'a> {
    rows: &'a WallRows,
    comm: &'a dyn Communicator,
    failure: Mutex<Option<TimestepError>>,
}

impl GmresOperator for RowsOperator<'_> {
    fn nrows(&self) -> usize {
        self.rows.n_rows()
    }
    fn ncols(&self) -> usize {
        self.rows.n_rows()
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        match gather_whole(self.comm, self.rows, x) {
            Ok(w) => self.rows.apply(&w, y),
            Err(e) => {
                let mut slot = self.failure.lock().unwrap_or_else(|e| e.into_inner());
                slot.get_or_insert(e);
                y.fill(f64::NAN);
            }
        }
    }
}

/// The block-Jacobi preconditioner on this rank's rows.
struct BlockJacobi<'a>(&'a WallRows);

impl Preconditioner for BlockJacobi<'_> {
    fn nrows(&self) -> usize {
        self.0.n_rows()
    }
    fn apply(&self, v: &[f64], z: &mut [f64]) {
        self.0.precondition(v, z);
    }
}

/// Solve the split system `system` for the boundary velocity `data` (every wall's, the same on
/// every rank; `scale` as in [`WallSystem::solve_formed`]), starting from the densities
/// `guess` (every wall's: the last step's, which the cells change little; `None`: zero);
/// collective over the ranks of `comm`, which must be those the rows were split over. Returns
/// the solution (the same on every rank) and the GMRES iterations.
///
/// # Errors
/// The data's checks ([`WallSystem::check_data`]), a failed exchange, or GMRES not meeting
/// [`WALL_ROWS_TOL`]; every rank returns the same outcome.
pub(in crate::timestep) fn solve_over_ranks(
    comm: &dyn Communicator,
    system: &WallSystem,
    data: &[f64],
    scale: f64,
    guess: Option<&[f64]>,
    ws: &mut GmresWorkspace,
) -> Result<(WallSolution, usize), TimestepError> {
    let rows = system
        .rows()
        .ok_or_else(|| TimestepError::Wall("not split".into()))?;
    if comm.size() != rows.share().ranks || comm.rank() != rows.share().rank {
        return Err(TimestepError::Comm(CommError::Ranks {
            what: "ranks the walls' rows were split over",
            got: rows.share().ranks,
            ranks: comm.size(),
        }));
    }
    // The same data on every rank: the checks agree.
    system.check_data(data, scale)?;
    let b = rows.restrict(data);
    let op = RowsOperator {
        rows,
        comm,
        failure: Mutex::new(None),
    };
    let sums = RankSums::new(comm);
    let params = GmresParams {
        tol: WALL_ROWS_TOL,
        restart: 100,
        max_iters: 500,
        min_cycle_reduction: 1e-3,
    };
    let mut x = vec![0.0; rows.n_rows()];
    let x0 = guess.map(|g| rows.restrict(g));
    let report = gmres_with(
        &op,
        &BlockJacobi(rows),
        &b,
        x0.as_deref(),
        &mut x,
        &params,
        ws,
        &sums,
    );
    if let Some(e) = sums.failure() {
        return Err(TimestepError::Comm(e));
    }
    if let Some(e) = op.failure.into_inner().unwrap_or_else(|e| e.into_inner()) {
        return Err(e);
    }
    let report = report?;
    let densities = gather_whole(comm, rows, &x)?;
    let solution = system.solution(densities, data)?;
    Ok((solution, report.iterations))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::timestep::gmres::gmres;
    use crate::timestep::operator::LinearOperator;
    use crate::vesicle::shapes;
    use crate::wall::{RowShare, Wall, WallKind, WallParams};

    /// An ellipsoidal container around a sphere (the walls of `tests/mpi_run.rs`).
    fn walls() -> Vec<Wall> {
        let mut s = shapes::sphere(8, 0.6).unwrap();
        s.translate([0.0, 0.0, -2.9]);
        vec![
            Wall::new(
                WallKind::Container,
                shapes::ellipsoid(12, [6.0, 6.0, 4.5]).unwrap(),
            )
            .unwrap(),
            Wall::new(WallKind::Body, s).unwrap(),
        ]
    }

    /// Every rank's rows on one process: `A M⁻¹` of the ranks together, on whole vectors.
    struct AllRanks(Vec<WallSystem>);

    impl AllRanks {
        fn rows(&self) -> impl Iterator<Item = &WallRows> {
            self.0.iter().map(|s| s.rows().expect("split"))
        }
        fn precondition(&self, v: &[f64]) -> Vec<f64> {
            let mut z = vec![0.0; v.len()];
            for r in self.rows() {
                let mine = r.unknowns(r.share().rank);
                let vr: Vec<f64> = mine.iter().map(|&i| v[i]).collect();
                let mut zr = vec![0.0; vr.len()];
                r.precondition(&vr, &mut zr);
                for (&i, x) in mine.iter().zip(zr) {
                    z[i] = x;
                }
            }
            z
        }
    }

    impl LinearOperator for AllRanks {
        fn nrows(&self) -> usize {
            self.0[0].n_unknowns()
        }
        fn apply(&self, x: &[f64], y: &mut [f64]) {
            let z = self.precondition(x);
            for r in self.rows() {
                let mut yr = vec![0.0; r.n_rows()];
                r.apply(&z, &mut yr);
                for (&i, v) in r.unknowns(r.share().rank).iter().zip(yr) {
                    y[i] = v;
                }
            }
        }
    }

    /// The block-Jacobi GMRES of the split system, the ranks emulated on one process, against
    /// the whole system's direct solve, for the data of a shear flow on walls at rest (the
    /// walls' densities cancel it inside the container).
    #[test]
    fn the_split_solve_meets_the_direct_solve() {
        let params = WallParams::default();
        let whole = WallSystem::new(walls(), params).unwrap();
        let n = whole.n_unknowns();
        let mut data = vec![0.0; n];
        let mut offset = 0;
        for w in whole.walls() {
            let np = w.n_points();
            for (j, x) in w.geometry().x.iter().enumerate() {
                data[offset + j] = -x[2];
            }
            offset += 3 * np;
        }
        let direct = whole.solve_formed(&data, 0.0).unwrap();
        let exact: Vec<f64> = (0..2).flat_map(|k| direct.density(k).to_vec()).collect();
        let size = exact.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        for ranks in [2, 3, 4] {
            let all = AllRanks(
                (0..ranks)
                    .map(|rank| {
                        WallSystem::new_share(walls(), params, RowShare { rank, ranks }).unwrap()
                    })
                    .collect(),
            );
            let gp = GmresParams {
                tol: WALL_ROWS_TOL,
                restart: 100,
                max_iters: 500,
                min_cycle_reduction: 1e-3,
            };
            let mut y = vec![0.0; n];
            let mut ws = GmresWorkspace::default();
            let report = gmres(
                &all,
                &crate::timestep::operator::Identity::new(n),
                &data,
                None,
                &mut y,
                &gp,
                &mut ws,
            )
            .unwrap();
            let psi = all.precondition(&y);
            let e = psi
                .iter()
                .zip(&exact)
                .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
            eprintln!(
                "{ranks} ranks: {} iterations, densities {:.1e} of their largest",
                report.iterations,
                e / size
            );
            assert!(e <= 1e-11 * size, "{ranks} ranks: {e:.1e}");
            // The velocity on a plane through the body, cut by the container: the walls'
            // near-zone evaluation at points close to them turns a change of 1e-14 of the
            // densities into about 3e-9 (measured with a perturbation of the direct solve's
            // densities), so the split solve's field is held to 1e-8 of its largest value.
            let sol = whole.solution(psi, &data).unwrap();
            let mut field =
                crate::wall::WallField::new(&whole, crate::vesicle::NearParams::default()).unwrap();
            let plane: Vec<[f64; 3]> = (0..15)
                .flat_map(|i| {
                    (0..15).map(move |j| {
                        let s = |k: usize| -5.8 + 11.6 * k as f64 / 14.0;
                        [s(i), s(j), -2.9]
                    })
                })
                .collect();
            let fluid = field.in_fluid(&plane).unwrap();
            let pts: Vec<[f64; 3]> = plane
                .into_iter()
                .zip(fluid)
                .filter_map(|(x, f)| f.then_some(x))
                .collect();
            let (mut u1, mut u2) = (vec![0.0; 3 * pts.len()], vec![0.0; 3 * pts.len()]);
            field.velocity(&direct, &pts, &mut u1).unwrap();
            field.velocity(&sol, &pts, &mut u2).unwrap();
            let d = u1
                .iter()
                .zip(&u2)
                .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
            let largest = u1.iter().fold(0.0_f64, |m, a| m.max(a.abs()));
            eprintln!("{ranks} ranks: the field differs by {d:.1e} of {largest:.2} at most");
            assert!(d <= 1e-8 * largest, "{ranks} ranks: field {d:.1e}");
        }
    }
}
