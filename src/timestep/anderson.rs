//! Anderson acceleration of a fixed-point iteration `x = G(x)`.
//!
//! Plain iteration `x_{k+1} = G(x_k)` converges like `ρᵏ`, `ρ` the contraction of `G` near its
//! fixed point. Anderson's mixing (D. G. Anderson, *Iterative procedures for nonlinear integral
//! equations*, J. ACM 12, 1965; in the form of H. F. Walker & P. Ni, *Anderson acceleration for
//! fixed-point iterations*, SIAM J. Numer. Anal. 49, 2011) keeps the last `m` differences of the
//! residuals `f_k = G(x_k) − x_k` and of the outputs `g_k = G(x_k)`,
//!
//! ```text
//!     ΔF = [f_{k−m+1} − f_{k−m}, …, f_k − f_{k−1}],      ΔG = [g_{k−m+1} − g_{k−m}, …, g_k − g_{k−1}],
//! ```
//!
//! finds the combination of them that best cancels the newest residual and takes the same
//! combination of the outputs:
//!
//! ```text
//!     γ = argmin_γ ‖f_k − ΔF γ‖₂ ,      x_{k+1} = g_k − ΔG γ .
//! ```
//!
//! For a linear `G(x) = M x + b` this is GMRES on `(I − M) x = b` in exact arithmetic while
//! `m ≥ k` (Walker & Ni, Theorem 2.2), so a contraction of 0.5–0.6 a pass, which plain
//! iteration needs 13 passes to bring to 10⁻³, takes a handful.
//!
//! The unknowns come as **blocks** (a cell's tension and membrane velocity in
//! [`crate::timestep::suspension::Suspension`]'s start-up), and the inner products are formed per block and
//! handed to a caller's reduction, which sums them in an order of its choosing (over ranks: the
//! cells' global order, so that every rank count gives the same `γ` bit for bit). The
//! least-squares problem is solved by its `m × m` normal equations with a small ridge
//! (`m ≤ 5`: the conditioning of the normal equations is not what limits a handful of
//! passes); a singular system drops the history and the step is the plain one.
//!
//! ```
//! use mobo::timestep::anderson::Anderson;
//!
//! // x = G(x) = 0.6 R x + b, with R a rotation: plain iteration contracts by 0.6 a pass.
//! let (c, s) = (0.8_f64, 0.6_f64);
//! let g = |x: &[f64]| vec![0.6 * (c * x[0] - s * x[1]) + 1.0, 0.6 * (s * x[0] + c * x[1]) + 2.0];
//! let mut acc = Anderson::new(3);
//! let mut x = vec![0.0, 0.0];
//! for _ in 0..4 {
//!     let gx = g(&x);
//!     x = acc
//!         .next(&[x.clone()], &[gx], |rows: Vec<Vec<f64>>, _width| -> Result<Vec<f64>, ()> {
//!             Ok(rows[0].clone())
//!         })
//!         .unwrap()
//!         .remove(0);
//! }
//! // The fixed point solves (I − 0.6 R) x = b; two unknowns: exact after three passes.
//! let r = [x[0] - g(&x)[0], x[1] - g(&x)[1]];
//! assert!(r[0].hypot(r[1]) < 1e-12);
//! ```

use std::collections::VecDeque;

/// One vector per block.
type Blocks = Vec<Vec<f64>>;

/// A residual `f` and an output `g` (or their differences between passes), per block.
#[derive(Clone, Debug)]
struct Pair {
    f: Blocks,
    g: Blocks,
}

/// Anderson's mixing over blocks of unknowns (module docs): the history of the last passes.
#[derive(Clone, Debug)]
pub struct Anderson {
    depth: usize,
    /// The previous pass's residual and output.
    last: Option<Pair>,
    /// `(Δf, Δg)` per kept pass (oldest first).
    history: VecDeque<Pair>,
}

impl Anderson {
    /// Mixing over the last `depth` differences (`depth = 0`: plain iteration).
    pub fn new(depth: usize) -> Self {
        Anderson {
            depth,
            last: None,
            history: VecDeque::new(),
        }
    }

    /// Differences kept now (at most the depth).
    pub fn kept(&self) -> usize {
        self.history.len()
    }

    /// The next input from this pass's input `x` and output `g = G(x)` (per block, of equal
    /// shapes). `reduce` takes one row per block of partial inner products, of the width it is
    /// given (also when this rank has no block), and returns their sums over all blocks of
    /// every rank. Whether a block changed shape since the last pass is decided over every
    /// rank the same way (a sum of flags), so that every rank keeps the same history.
    pub fn next<E>(
        &mut self,
        x: &[Vec<f64>],
        g: &[Vec<f64>],
        mut reduce: impl FnMut(Vec<Vec<f64>>, usize) -> Result<Vec<f64>, E>,
    ) -> Result<Vec<Vec<f64>>, E> {
        let f: Vec<Vec<f64>> = x
            .iter()
            .zip(g)
            .map(|(x, g)| g.iter().zip(x).map(|(g, x)| g - x).collect())
            .collect();
        let same_shape = |a: &[Vec<f64>]| {
            a.len() == f.len() && a.iter().zip(&f).all(|(a, f)| a.len() == f.len())
        };
        // A change of shape (a block gained its membrane velocity) on any rank: every rank
        // starts afresh. (At the first pass no rank has a history.)
        let last = self.last.take();
        let changed = match &last {
            // Nothing is kept at depth 0 (on every rank): no flags to sum.
            None => true,
            Some(_) if self.depth == 0 => true,
            Some(last) => {
                let mine = f64::from(u8::from(!same_shape(&last.f)));
                let flags = (0..f.len()).map(|b| vec![if b == 0 { mine } else { 0.0 }]);
                reduce(flags.collect(), 1)?[0] > 0.0
            }
        };
        match last {
            Some(last) if !changed => {
                self.history.push_back(Pair {
                    f: diff(&f, &last.f),
                    g: diff(g, &last.g),
                });
                while self.history.len() > self.depth {
                    self.history.pop_front();
                }
            }
            _ => self.history.clear(),
        }
        self.last = Some(Pair {
            f: f.clone(),
            g: g.to_vec(),
        });
        // The history grows in step on every rank, so all of them skip the reduction together.
        let m = self.history.len();
        if m == 0 {
            return Ok(g.to_vec());
        }
        let width = m * (m + 1) / 2 + m;
        let rows: Vec<Vec<f64>> = (0..f.len())
            .map(|b| {
                let mut row = Vec::with_capacity(width);
                for (i, hi) in self.history.iter().enumerate() {
                    for hj in self.history.iter().take(i + 1) {
                        row.push(dot(&hi.f[b], &hj.f[b]));
                    }
                }
                for h in &self.history {
                    row.push(dot(&h.f[b], &f[b]));
                }
                row
            })
            .collect();
        let sums = reduce(rows, width)?;
        // A, m × m, row-major.
        let mut a = vec![0.0; m * m];
        let mut k = 0;
        for i in 0..m {
            for j in 0..=i {
                a[i * m + j] = sums[k];
                a[j * m + i] = sums[k];
                k += 1;
            }
        }
        let b: Vec<f64> = sums[k..k + m].to_vec();
        let Some(gamma) = solve_ridge(a, b) else {
            self.history.clear();
            return Ok(g.to_vec());
        };
        let mut next = g.to_vec();
        for (gam, h) in gamma.iter().zip(&self.history) {
            for (n, d) in next.iter_mut().zip(&h.g) {
                for (n, d) in n.iter_mut().zip(d) {
                    *n -= gam * d;
                }
            }
        }
        Ok(next)
    }
}

fn diff(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    a.iter()
        .zip(b)
        .map(|(a, b)| a.iter().zip(b).map(|(a, b)| a - b).collect())
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// `(A + ε max_i A_ii I) γ = b` by Gaussian elimination with partial pivoting (`A` row-major
/// `m × m`, symmetric positive semidefinite, `ε = 1e-12`); `None` when `A` is zero or the
/// result is not finite.
fn solve_ridge(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let m = b.len();
    let scale = (0..m).map(|i| a[i * m + i]).fold(0.0_f64, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for i in 0..m {
        a[i * m + i] += 1e-12 * scale;
    }
    for col in 0..m {
        let piv =
            (col..m).max_by(|&i, &j| a[i * m + col].abs().total_cmp(&a[j * m + col].abs()))?;
        if piv != col {
            for c in 0..m {
                a.swap(col * m + c, piv * m + c);
            }
            b.swap(col, piv);
        }
        let d = a[col * m + col];
        if d == 0.0 {
            return None;
        }
        for r in col + 1..m {
            let l = a[r * m + col] / d;
            for c in col..m {
                a[r * m + c] -= l * a[col * m + c];
            }
            b[r] -= l * b[col];
        }
    }
    let mut x = vec![0.0; m];
    for i in (0..m).rev() {
        let s: f64 = (i + 1..m).map(|j| a[i * m + j] * x[j]).sum();
        x[i] = (b[i] - s) / a[i * m + i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A linear contraction `G(x) = M x + b` on `n` unknowns, `M = Q D Qᵀ` with `Q` a random
    /// orthogonal matrix and the eigenvalues `D` spread over `[−ρ/2, ρ]`, `ρ` among them: plain
    /// iteration contracts by `ρ` a pass.
    fn linear_map(n: usize, rho: f64, seed: u64) -> (Vec<Vec<f64>>, Vec<f64>) {
        let mut s = seed;
        let mut rand = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        // Q by Gram–Schmidt on random columns.
        let mut q: Vec<Vec<f64>> = Vec::with_capacity(n);
        while q.len() < n {
            let mut v: Vec<f64> = (0..n).map(|_| rand()).collect();
            for _ in 0..2 {
                for u in &q {
                    let d = dot(&v, u);
                    for (v, u) in v.iter_mut().zip(u) {
                        *v -= d * u;
                    }
                }
            }
            let norm = dot(&v, &v).sqrt();
            if norm > 1e-6 {
                q.push(v.iter().map(|v| v / norm).collect());
            }
        }
        let eig: Vec<f64> = (0..n)
            .map(|k| rho * (1.0 - 1.5 * k as f64 / (n - 1) as f64))
            .collect();
        let m = (0..n)
            .map(|i| {
                (0..n)
                    .map(|j| (0..n).map(|k| q[k][i] * eig[k] * q[k][j]).sum())
                    .collect()
            })
            .collect();
        let b = (0..n).map(|_| rand()).collect();
        (m, b)
    }

    fn apply(m: &[Vec<f64>], b: &[f64], x: &[f64]) -> Vec<f64> {
        m.iter()
            .zip(b)
            .map(|(row, b)| row.iter().zip(x).map(|(a, x)| a * x).sum::<f64>() + b)
            .collect()
    }

    fn split(x: &[f64], at: usize) -> Vec<Vec<f64>> {
        vec![x[..at].to_vec(), x[at..].to_vec()]
    }

    /// The reduction of one rank: the blocks' rows summed in order.
    fn sum_rows(rows: Vec<Vec<f64>>, width: usize) -> Result<Vec<f64>, ()> {
        Ok((0..width)
            .map(|i| rows.iter().map(|r| r[i]).sum())
            .collect())
    }

    fn residual(m: &[Vec<f64>], b: &[f64], x: &[f64]) -> f64 {
        apply(m, b, x)
            .iter()
            .zip(x)
            .map(|(g, x)| (g - x).abs())
            .fold(0.0, f64::max)
    }

    /// Passes to bring the residual below `tol` (at most 400), plain (`depth = 0`) or mixed;
    /// and the last iterate.
    fn passes(m: &[Vec<f64>], b: &[f64], depth: usize, tol: f64) -> (usize, Vec<f64>) {
        let n = b.len();
        let mut acc = Anderson::new(depth);
        let mut x = vec![0.0; n];
        for k in 0..400 {
            if residual(m, b, &x) < tol {
                return (k, x);
            }
            let g = apply(m, b, &x);
            // The reduction sums the blocks' rows in order, as one rank does.
            let next = acc
                .next(&split(&x, n / 3), &split(&g, n / 3), sum_rows)
                .unwrap();
            x = next.concat();
        }
        (400, x)
    }

    /// The mixed iteration reaches the same fixed point as the plain one (checked against the
    /// plain iteration run to round-off, an independent reference), in far fewer passes.
    #[test]
    fn mixing_reaches_the_plain_fixed_point_in_fewer_passes() {
        for (n, rho, seed) in [(12, 0.6, 1), (40, 0.6, 2), (40, 0.8, 3)] {
            let (m, b) = linear_map(n, rho, seed);
            let (plain, reference) = passes(&m, &b, 0, 1e-14);
            let (fast, x) = passes(&m, &b, 5, 1e-10);
            let (plain3, _) = passes(&m, &b, 0, 1e-3);
            let (fast3, _) = passes(&m, &b, 3, 1e-3);
            let err = x
                .iter()
                .zip(&reference)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            println!(
                "n = {n}, ρ = {rho}: plain {plain} passes to 1e-14, mixed {fast} to 1e-10 \
                 (error {err:.1e}); to 1e-3: plain {plain3}, depth 3 {fast3}"
            );
            assert!(plain < 400 && fast < plain, "{fast} vs {plain}");
            assert!(fast3 < plain3, "{fast3} vs {plain3}");
            // The fixed point's condition number is at most 1/(1 − ρ).
            assert!(err < 1e-10 / (1.0 - rho) * 10.0, "{err:.2e}");
        }
    }

    /// Two ranks, one holding every block and one holding none (a rank of a suspension with
    /// fewer cells than ranks), take the same passes as one rank, bit for bit, including the
    /// pass at which a block changes shape (grows, as a cell's membrane velocity joins its
    /// tension): the empty rank sums rows of the width it is given and follows the same
    /// history.
    #[test]
    fn a_rank_without_blocks_keeps_in_step() {
        use std::sync::mpsc::channel;
        let (m, b) = linear_map(12, 0.7, 5);
        // Pass 0 sees only the first 4 unknowns of block 1 (a shorter block), later passes
        // the whole.
        let blocks = |x: &[f64], k: usize| {
            let mut v = split(x, 4);
            if k == 0 {
                v[1].truncate(4);
            }
            v
        };
        let run = |reduce: &mut dyn FnMut(Vec<Vec<f64>>, usize) -> Result<Vec<f64>, ()>| {
            let mut acc = Anderson::new(3);
            let mut x = vec![0.0; 12];
            let mut out = Vec::new();
            for k in 0..12 {
                let g = apply(&m, &b, &x);
                let next = acc
                    .next(&blocks(&x, k), &blocks(&g, k), &mut *reduce)
                    .unwrap()
                    .concat();
                x[..next.len()].copy_from_slice(&next);
                out.push(x.clone());
            }
            out
        };
        let alone = run(&mut sum_rows);
        // Rank 0 holds the blocks, rank 1 none; each reduction exchanges rows.
        let (to1, from0) = channel::<Vec<Vec<f64>>>();
        let (to0, from1) = channel::<Vec<Vec<f64>>>();
        let empty = std::thread::spawn(move || {
            let mut acc = Anderson::new(3);
            let mut calls = 0;
            for _ in 0..12 {
                acc.next(
                    &[],
                    &[],
                    |rows: Vec<Vec<f64>>, width| -> Result<Vec<f64>, ()> {
                        calls += 1;
                        let theirs = from0.recv().unwrap();
                        to0.send(rows.clone()).unwrap();
                        sum_rows(theirs.into_iter().chain(rows).collect(), width)
                    },
                )
                .unwrap();
            }
            (acc.kept(), calls)
        });
        let mut calls = 0;
        let shared = run(&mut |rows: Vec<Vec<f64>>, width| {
            calls += 1;
            to1.send(rows.clone()).unwrap();
            let theirs = from1.recv().unwrap();
            sum_rows(rows.into_iter().chain(theirs).collect(), width)
        });
        let (kept, empty_calls) = empty.join().unwrap();
        assert_eq!(shared, alone);
        assert_eq!((kept, empty_calls), (3, calls));
        assert!(calls > 12, "{calls}");
    }

    /// Depth 0 is plain iteration, bit for bit; a zero history gives the plain step.
    #[test]
    fn depth_zero_is_plain_iteration() {
        let (m, b) = linear_map(9, 0.5, 4);
        let mut acc = Anderson::new(0);
        let mut x = vec![0.0; 9];
        let mut y = x.clone();
        for _ in 0..5 {
            let g = apply(&m, &b, &x);
            x = acc
                .next(
                    &split(&x, 3),
                    &split(&g, 3),
                    |_, _| -> Result<Vec<f64>, ()> { panic!("no reduction without history") },
                )
                .unwrap()
                .concat();
            y = apply(&m, &b, &y);
            assert_eq!(x, y);
        }
        assert_eq!(acc.kept(), 0);
        // At a fixed point every difference vanishes: the plain step, no NaN.
        let fixed = passes(&m, &b, 0, 1e-15).1;
        let g = apply(&m, &b, &fixed);
        let mut acc = Anderson::new(2);
        for _ in 0..3 {
            let next = acc
                .next(&split(&fixed, 3), &split(&g, 3), sum_rows)
                .unwrap()
                .concat();
            assert!(next.iter().all(|v| v.is_finite()));
        }
    }

    /// The normal equations' solver against a known solution, and its refusals.
    #[test]
    fn ridge_solver_solves_and_refuses() {
        let a = vec![4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let want = [1.0, -2.0, 0.5];
        let b: Vec<f64> = a
            .chunks_exact(3)
            .map(|r| r.iter().zip(&want).map(|(a, x)| a * x).sum())
            .collect();
        let x = solve_ridge(a, b).unwrap();
        for (x, w) in x.iter().zip(want) {
            assert!((x - w).abs() < 1e-10, "{x} vs {w}");
        }
        assert!(solve_ridge(vec![0.0; 4], vec![0.0, 0.0]).is_none());
        assert!(solve_ridge(vec![f64::NAN], vec![1.0]).is_none());
    }
}
