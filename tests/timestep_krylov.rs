//! The Krylov layer of `mobo::timestep`: restarted right-preconditioned GMRES, the operator and
//! preconditioner traits, against independent references (faer's dense LU, exact Krylov
//! properties, naive residuals computed here).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use faer::linalg::solvers::Solve;
use faer::Mat;
use mobo::timestep::{
    gmres, BlockDiagonal, FnOperator, FnPreconditioner, GmresParams, GmresReport, GmresWorkspace,
    Identity, LinearOperator, Preconditioner, TimestepError,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

// ---------------------------------------------------------------------------------------------
// Allocation counter (per thread, so that tests running in parallel do not disturb each other).

struct Counting;

thread_local! {
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn bump() {
    let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        bump();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        bump();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        bump();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCS.with(|c| c.get())
}

// ---------------------------------------------------------------------------------------------
// Independent helpers (naive loops; faer only for LU, QR and singular values).

fn rng(seed: u64) -> StdRng {
    StdRng::seed_from_u64(seed)
}

fn gaussian(r: &mut StdRng, nrows: usize, ncols: usize, scale: f64) -> Mat<f64> {
    Mat::from_fn(nrows, ncols, |_, _| {
        scale * r.sample::<f64, _>(StandardNormal)
    })
}

fn random_vec(r: &mut StdRng, n: usize) -> Vec<f64> {
    (0..n).map(|_| r.random_range(-1.0..1.0)).collect()
}

fn matvec(a: &Mat<f64>, x: &[f64]) -> Vec<f64> {
    (0..a.nrows())
        .map(|i| (0..a.ncols()).map(|j| a[(i, j)] * x[j]).sum())
        .collect()
}

fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// `‖b − A x‖ / ‖b‖`, computed here.
fn rel_residual(a: &Mat<f64>, x: &[f64], b: &[f64]) -> f64 {
    let ax = matvec(a, x);
    let r: Vec<f64> = b.iter().zip(&ax).map(|(bi, ai)| bi - ai).collect();
    norm(&r) / norm(b)
}

fn rel_diff(x: &[f64], y: &[f64]) -> f64 {
    let d: Vec<f64> = x.iter().zip(y).map(|(a, b)| a - b).collect();
    norm(&d) / norm(y)
}

fn lu_solve(a: &Mat<f64>, b: &[f64]) -> Vec<f64> {
    let mut rhs = Mat::from_fn(b.len(), 1, |i, _| b[i]);
    a.partial_piv_lu().solve_in_place(rhs.as_mut());
    (0..b.len()).map(|i| rhs[(i, 0)]).collect()
}

fn cond2(a: &Mat<f64>) -> f64 {
    let s = a.singular_values().unwrap();
    let (hi, lo) = s
        .iter()
        .fold((0.0f64, f64::INFINITY), |(h, l), &v| (h.max(v), l.min(v)));
    hi / lo
}

/// The forward-error bound `‖x − x*‖/‖x*‖ ≤ κ₂(A) (‖b − A x‖/‖b‖ + c n ε)` (the `c n ε` term
/// covers the rounding of the LU reference and of the residual itself).
fn forward_bound(kappa: f64, relres: f64, n: usize) -> f64 {
    kappa * (relres + 10.0 * n as f64 * f64::EPSILON)
}

fn solve(
    a: &(impl LinearOperator + ?Sized),
    m: &(impl Preconditioner + ?Sized),
    b: &[f64],
    params: &GmresParams,
) -> (Vec<f64>, Result<GmresReport, TimestepError>) {
    let n = b.len();
    let mut ws = GmresWorkspace::new(n, params.restart);
    let mut x = vec![0.0; n];
    let rep = gmres(a, m, b, None, &mut x, params, &mut ws);
    (x, rep)
}

/// Nonsymmetric, strictly diagonally dominant: off-diagonal entries uniform in (−1, 1), diagonal
/// `1.1 Σ_j |a_ij|` with alternating sign.
fn diag_dominant(r: &mut StdRng, n: usize) -> Mat<f64> {
    let mut a = Mat::<f64>::from_fn(n, n, |i, j| {
        if i == j {
            0.0
        } else {
            r.random_range(-1.0..1.0)
        }
    });
    for i in 0..n {
        let s: f64 = (0..n).map(|j| a[(i, j)].abs()).sum();
        a[(i, i)] = if i % 2 == 0 { 1.1 * s } else { -1.1 * s };
    }
    a
}

/// Cyclic shift `A e_i = e_{i+1 mod n}`: with `b = e₁`, GMRES makes no progress before step `n`.
fn cyclic_shift(n: usize) -> Mat<f64> {
    Mat::from_fn(n, n, |i, j| if i == (j + 1) % n { 1.0 } else { 0.0 })
}

// ---------------------------------------------------------------------------------------------

#[test]
fn dense_diagonally_dominant_systems_match_lu() {
    let mut r = rng(1);
    let tol = 1e-12;
    for n in [50, 100, 200, 400] {
        let a = diag_dominant(&mut r, n);
        let b = random_vec(&mut r, n);
        let params = GmresParams {
            tol,
            restart: 50,
            max_iters: 500,
            ..Default::default()
        };
        let (x, rep) = solve(&a, &Identity::new(n), &b, &params);
        let rep = rep.unwrap();
        let relres = rel_residual(&a, &x, &b);
        let x_lu = lu_solve(&a, &b);
        let kappa = cond2(&a);
        let err = rel_diff(&x, &x_lu);
        let bound = forward_bound(kappa, relres, n);
        println!(
            "n = {n:3}: {} iterations, {} restarts, reported residual {:.2e}, recomputed {:.2e}, \
             κ₂ = {kappa:.2}, ‖x − x_LU‖/‖x_LU‖ = {err:.2e} (bound {bound:.2e})",
            rep.iterations, rep.restarts, rep.relative_residual, relres
        );
        assert!(rep.converged && rep.relative_residual <= tol);
        assert!(relres <= tol, "recomputed residual {relres:e}");
        assert!(
            (relres - rep.relative_residual).abs() <= 1e-2 * relres + 1e-16,
            "report {:e} vs recomputed {relres:e}",
            rep.relative_residual
        );
        assert!(err <= bound, "error {err:e} above bound {bound:e}");
        assert!(rep.iterations < n);
    }
}

#[test]
fn k_distinct_eigenvalues_converge_in_k_iterations() {
    // A = S D S⁻¹, D with k distinct eigenvalues (each repeated), S non-orthogonal: the minimal
    // polynomial of A has degree k, so the Krylov space of any b has dimension ≤ k and GMRES is
    // exact after k steps.
    let mut r = rng(2);
    let n = 150;
    let lambdas = [1.0, 2.0, 3.5, 5.0, -4.0, 9.0, 12.0];
    let k = lambdas.len();
    let s = {
        let mut s = gaussian(&mut r, n, n, 0.5 / (n as f64).sqrt());
        for i in 0..n {
            s[(i, i)] += 1.0;
        }
        s
    };
    let mut s_inv = Mat::<f64>::identity(n, n);
    s.partial_piv_lu().solve_in_place(s_inv.as_mut());
    let d = Mat::from_fn(n, n, |i, j| if i == j { lambdas[i % k] } else { 0.0 });
    let a = &s * &d * &s_inv;
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-10,
        restart: 50,
        max_iters: 50,
        ..Default::default()
    };
    let (x, rep) = solve(&a, &Identity::new(n), &b, &params);
    let rep = rep.unwrap();
    let relres = rel_residual(&a, &x, &b);
    println!(
        "{k} distinct eigenvalues, n = {n}: {} iterations, residual {:.2e} (recomputed {relres:.2e})",
        rep.iterations, rep.relative_residual
    );
    assert_eq!(rep.restarts, 0);
    assert!(rep.iterations <= k);
    // ... and it needs all k (no polynomial of degree k − 1 vanishes on 7 distinct points).
    assert_eq!(rep.iterations, k);
    assert!(relres <= 1e-10);
    // The same with only k − 1 steps allowed fails, with the report.
    let (_, rep2) = solve(
        &a,
        &Identity::new(n),
        &b,
        &GmresParams {
            max_iters: k - 1,
            ..params
        },
    );
    let err = rep2.unwrap_err();
    let rep2 = err.report().unwrap();
    println!(
        "  with k − 1 = {} steps: residual {:.2e}",
        k - 1,
        rep2.relative_residual
    );
    assert!(rep2.relative_residual > 1e-6);
}

#[test]
fn cyclic_shift_needs_exactly_n_iterations_without_restart() {
    // Classic worst case: A = cyclic shift, b = e₁. K_j = span{e₁, …, e_j} ⟂ A K_j ∌ e₁ for j < n,
    // so the residual stays ‖b‖ until the n-th step, where it drops to zero.
    let n = 40;
    let a = cyclic_shift(n);
    let mut b = vec![0.0; n];
    b[0] = 1.0;
    let params = GmresParams {
        tol: 1e-12,
        restart: n,
        max_iters: n,
        ..Default::default()
    };
    let (x, rep) = solve(&a, &Identity::new(n), &b, &params);
    let rep = rep.unwrap();
    println!(
        "cyclic shift n = {n}: {} iterations, residual {:.2e}",
        rep.iterations, rep.relative_residual
    );
    assert_eq!(rep.iterations, n);
    assert_eq!(rep.restarts, 0);
    // Exact solution: x = e_n (A e_n = e₁).
    for (i, xi) in x.iter().enumerate() {
        let expect: f64 = if i == n - 1 { 1.0 } else { 0.0 };
        assert!((xi - expect).abs() < 1e-14, "x[{i}] = {xi}");
    }
}

#[test]
fn random_nonnormal_matrix_converges_in_at_most_n_iterations() {
    // Gaussian matrix, eigenvalues filling the unit disc around 0: full GMRES needs close to n
    // steps, and at most n.
    let mut r = rng(3);
    let n = 60;
    let a = gaussian(&mut r, n, n, 1.0 / (n as f64).sqrt());
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-10,
        restart: n,
        max_iters: n,
        ..Default::default()
    };
    let (x, rep) = solve(&a, &Identity::new(n), &b, &params);
    let rep = rep.unwrap();
    let relres = rel_residual(&a, &x, &b);
    let kappa = cond2(&a);
    let err = rel_diff(&x, &lu_solve(&a, &b));
    println!(
        "Gaussian n = {n}, κ₂ = {kappa:.1}: {} iterations, residual {relres:.2e}, error vs LU \
         {err:.2e}",
        rep.iterations
    );
    assert!(rep.iterations <= n && rep.restarts == 0);
    assert!(relres <= 1e-10);
    assert!(err <= forward_bound(kappa, relres, n));
}

#[test]
fn restarted_gmres_converges_with_monotone_residuals() {
    // A = 2.5 I + G/√n: the field of values lies in Re z ≥ 2.5 − ‖(G + Gᵀ)/2√n‖ > 0, so GMRES(m)
    // converges for every m (Elman 1982); the true residual must not increase across restarts.
    let mut r = rng(4);
    let n = 300;
    let mut a = gaussian(&mut r, n, n, 1.0 / (n as f64).sqrt());
    for i in 0..n {
        a[(i, i)] += 2.5;
    }
    let b = random_vec(&mut r, n);
    let x_lu = lu_solve(&a, &b);
    let kappa = cond2(&a);
    let tol = 1e-10;
    let mut iters = Vec::new();
    for m in [3, 10, 30, 300] {
        let params = GmresParams {
            tol,
            restart: m,
            max_iters: 2000,
            ..Default::default()
        };
        let (x, rep) = solve(&a, &Identity::new(n), &b, &params);
        let rep = rep.unwrap();
        let relres = rel_residual(&a, &x, &b);
        let err = rel_diff(&x, &x_lu);
        println!(
            "GMRES({m:3}): {:3} iterations, {:2} restarts, residual {relres:.2e}, error vs LU \
             {err:.2e}; residual per cycle {:?}",
            rep.iterations,
            rep.restarts,
            rep.cycle_residuals
                .iter()
                .map(|v| format!("{v:.1e}"))
                .collect::<Vec<_>>()
        );
        assert!(rep.converged && relres <= tol);
        assert!(err <= forward_bound(kappa, relres, n));
        assert_eq!(rep.cycle_residuals.len(), rep.restarts + 1);
        for w in rep.cycle_residuals.windows(2) {
            assert!(w[1] <= w[0], "residual increased across a restart: {w:?}");
        }
        if m < 30 {
            assert!(rep.restarts > 0);
        }
        iters.push(rep.iterations);
    }
    // Restarting never helps on this problem: GMRES(3) needs at least as many steps as full GMRES.
    assert!(iters[0] >= iters[3] && iters[1] >= iters[3]);
}

/// A block-dominant matrix: dense, ill-conditioned, nonsymmetric diagonal blocks of different
/// sizes (eigenvalues spread over 1 … 10³, like a bending operator) and a weak dense coupling.
fn block_dominant(r: &mut StdRng, sizes: &[usize], coupling: f64) -> Mat<f64> {
    let n: usize = sizes.iter().sum();
    let mut a = gaussian(r, n, n, coupling / (n as f64).sqrt());
    let mut o = 0;
    for &s in sizes {
        let q = gaussian(r, s, s, 1.0).qr().compute_Q();
        let lam = Mat::from_fn(s, s, |i, j| {
            if i == j {
                10f64.powf(3.0 * i as f64 / (s - 1) as f64)
            } else {
                0.0
            }
        });
        let nonsym = gaussian(r, s, s, 0.2 / (s as f64).sqrt());
        let blk = &q * &lam * q.transpose() + &nonsym;
        for j in 0..s {
            for i in 0..s {
                a[(o + i, o + j)] = blk[(i, j)];
            }
        }
        o += s;
    }
    a
}

#[test]
fn block_diagonal_preconditioner_cuts_iterations() {
    let mut r = rng(5);
    let sizes = [12, 30, 18, 45, 24, 36, 15, 40, 27, 33];
    let n: usize = sizes.iter().sum();
    let a = block_dominant(&mut r, &sizes, 0.3);
    let b = random_vec(&mut r, n);
    let tol = 1e-10;
    let params = GmresParams {
        tol,
        restart: n,
        max_iters: n,
        ..Default::default()
    };
    let m = BlockDiagonal::from_diagonal_of(a.as_ref(), &sizes).unwrap();
    assert_eq!(m.num_blocks(), sizes.len());
    assert_eq!(m.block_sizes().collect::<Vec<_>>(), sizes);
    assert_eq!(Preconditioner::nrows(&m), n);

    let (x_plain, rep_plain) = solve(&a, &Identity::new(n), &b, &params);
    let (x_prec, rep_prec) = solve(&a, &m, &b, &params);
    let (rep_plain, rep_prec) = (rep_plain.unwrap(), rep_prec.unwrap());
    let x_lu = lu_solve(&a, &b);
    let kappa = cond2(&a);
    let (res_p, res_m) = (
        rel_residual(&a, &x_plain, &b),
        rel_residual(&a, &x_prec, &b),
    );
    let (err_p, err_m) = (rel_diff(&x_plain, &x_lu), rel_diff(&x_prec, &x_lu));
    println!(
        "n = {n}, {} blocks, κ₂(A) = {kappa:.0}: unpreconditioned {} iterations (residual \
         {res_p:.2e}, error {err_p:.2e}); block-diagonal {} iterations (residual {res_m:.2e}, \
         error {err_m:.2e}); ratio {:.1}",
        sizes.len(),
        rep_plain.iterations,
        rep_prec.iterations,
        rep_plain.iterations as f64 / rep_prec.iterations as f64
    );
    assert!(res_p <= tol && res_m <= tol);
    assert!(err_p <= forward_bound(kappa, res_p, n));
    assert!(err_m <= forward_bound(kappa, res_m, n));
    assert!(
        rep_prec.iterations * 3 <= rep_plain.iterations,
        "preconditioned {} vs plain {} iterations",
        rep_prec.iterations,
        rep_plain.iterations
    );
    // Same solution from both.
    assert!(rel_diff(&x_prec, &x_plain) <= 2.0 * forward_bound(kappa, tol, n));
}

#[test]
fn block_diagonal_apply_matches_dense_block_solves() {
    // M⁻¹ v against an explicit inverse of each block (faer LU on the block, solved separately).
    let mut r = rng(6);
    let sizes = [1, 7, 3, 20, 2];
    let n: usize = sizes.iter().sum();
    let a = block_dominant(&mut r, &[7, 3, 20], 0.1);
    let blocks: Vec<Mat<f64>> = sizes
        .iter()
        .map(|&s| {
            let mut bk = gaussian(&mut r, s, s, 1.0);
            for i in 0..s {
                bk[(i, i)] += 3.0;
            }
            bk
        })
        .collect();
    let views: Vec<_> = blocks.iter().map(|bk| bk.as_ref()).collect();
    let m = BlockDiagonal::new(&views).unwrap();
    let v = random_vec(&mut r, n);
    let mut z = vec![0.0; n];
    m.apply(&v, &mut z);
    let mut o = 0;
    for bk in &blocks {
        let s = bk.nrows();
        let zk = lu_solve(bk, &v[o..o + s]);
        assert!(rel_diff(&z[o..o + s], &zk) < 1e-13);
        // and B_k z_k = v_k
        assert!(rel_diff(&matvec(bk, &z[o..o + s]), &v[o..o + s]) < 1e-12);
        o += s;
    }
    // from_diagonal_of takes the blocks of a matrix.
    let m2 = BlockDiagonal::from_diagonal_of(a.as_ref(), &[7, 3, 20]).unwrap();
    assert_eq!(m2.num_blocks(), 3);
}

#[test]
fn matrix_free_closure_operator_matches_dense() {
    // 1-D convection–diffusion −u'' + c u' on n points (nonsymmetric), matrix-free and assembled.
    let n = 200;
    let (d, c) = (2.0, 0.6);
    let op = FnOperator::new(n, move |x: &[f64], y: &mut [f64]| {
        for i in 0..n {
            let left = if i > 0 { x[i - 1] } else { 0.0 };
            let right = if i + 1 < n { x[i + 1] } else { 0.0 };
            y[i] = d * x[i] - (1.0 + c) * left - (1.0 - c) * right + 0.5 * x[i];
        }
    });
    let dense = Mat::from_fn(n, n, |i, j| {
        if i == j {
            d + 0.5
        } else if j + 1 == i {
            -(1.0 + c)
        } else if i + 1 == j {
            -(1.0 - c)
        } else {
            0.0
        }
    });
    let mut r = rng(7);
    let x = random_vec(&mut r, n);
    let mut y = vec![0.0; n];
    op.apply(&x, &mut y);
    assert!(rel_diff(&y, &matvec(&dense, &x)) < 1e-15);
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-11,
        restart: 40,
        max_iters: 5000,
        ..Default::default()
    };
    let (x1, rep1) = solve(&op, &Identity::new(n), &b, &params);
    let (x2, rep2) = solve(&dense, &Identity::new(n), &b, &params);
    let (rep1, rep2) = (rep1.unwrap(), rep2.unwrap());
    let relres = rel_residual(&dense, &x1, &b);
    println!(
        "convection–diffusion n = {n}: closure {} iterations ({} restarts), dense {} iterations, \
         residual {relres:.2e}",
        rep1.iterations, rep1.restarts, rep2.iterations
    );
    assert!(relres <= 1e-11);
    let kappa = cond2(&dense);
    assert!(rel_diff(&x1, &lu_solve(&dense, &b)) <= forward_bound(kappa, relres, n));
    assert!(rel_diff(&x1, &x2) <= 2.0 * forward_bound(kappa, 1e-11, n));
}

#[test]
fn non_convergence_returns_err_with_report() {
    // GMRES(10) on the cyclic shift with b = e₁ stagnates completely: every restart starts from
    // x = 0 with residual exactly ‖b‖.
    let n = 40;
    let a = cyclic_shift(n);
    let mut b = vec![0.0; n];
    b[0] = 1.0;
    let params = GmresParams {
        tol: 1e-8,
        restart: 10,
        max_iters: 100,
        ..Default::default()
    };
    // With the stagnation test (the default) it stops after the first cycle, with the residual
    // history in the message.
    let (x, res) = solve(&a, &Identity::new(n), &b, &params);
    let err = res.unwrap_err();
    println!("stagnating GMRES(10), stagnation test on: {err}");
    assert!(err.to_string().contains("stagnated"), "{err}");
    assert!(err.to_string().contains("1.00e0"), "{err}");
    let TimestepError::Stagnated(rep) = &err else {
        panic!("expected Stagnated, got {err:?}");
    };
    assert_eq!(rep.iterations, 10);
    assert_eq!(rep.restarts, 0);
    assert_eq!(rep.cycle_residuals, vec![1.0]);
    assert!(x.iter().all(|&v| v == 0.0));
    // Without it, GMRES grinds on to max_iters.
    let params = GmresParams {
        min_cycle_reduction: 0.0,
        ..params
    };
    let (x, res) = solve(&a, &Identity::new(n), &b, &params);
    let err = res.unwrap_err();
    println!("stagnating GMRES(10), stagnation test off: {err}");
    assert!(err.to_string().contains("did not converge"));
    let TimestepError::NotConverged(rep) = &err else {
        panic!("expected NotConverged, got {err:?}");
    };
    assert_eq!(rep.iterations, 100);
    assert_eq!(rep.restarts, 9);
    assert!(!rep.converged);
    assert_eq!(rep.relative_residual, 1.0);
    assert!(rep.cycle_residuals.iter().all(|&v| v == 1.0));
    assert!(x.iter().all(|&v| v == 0.0));

    // A generic case stopped early: the report's residual is the true residual of the returned x.
    let mut r = rng(8);
    let n = 100;
    let a = gaussian(&mut r, n, n, 1.0 / (n as f64).sqrt());
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-10,
        restart: 4,
        max_iters: 10,
        ..Default::default()
    };
    let (x, res) = solve(&a, &Identity::new(n), &b, &params);
    let rep = res.unwrap_err().report().unwrap().clone();
    let relres = rel_residual(&a, &x, &b);
    println!(
        "stopped after {} iterations, {} restarts: reported residual {:.4e}, recomputed {relres:.4e}",
        rep.iterations, rep.restarts, rep.relative_residual
    );
    assert_eq!(rep.iterations, 10);
    assert_eq!(rep.restarts, 2);
    assert!((rep.relative_residual - relres).abs() <= 1e-12 * relres);
    assert!(relres > 1e-10);
}

#[test]
fn singular_operator_reports_breakdown() {
    // A = diag(1, 2, 0), b = (1, 1, 1): the Krylov space {b, Ab, A²b} = ℝ³ is invariant after 3
    // steps; the best residual is the e₃ component, 1/√3.
    let a = Mat::from_fn(3, 3, |i, j| if i == j { [1.0, 2.0, 0.0][i] } else { 0.0 });
    let b = [1.0, 1.0, 1.0];
    let params = GmresParams {
        tol: 1e-10,
        restart: 10,
        max_iters: 100,
        ..Default::default()
    };
    let (x, res) = solve(&a, &Identity::new(3), &b, &params);
    let err = res.unwrap_err();
    println!("{err}");
    let TimestepError::Breakdown(rep) = &err else {
        panic!("expected Breakdown, got {err:?}");
    };
    assert!((rep.relative_residual - 1.0 / 3f64.sqrt()).abs() < 1e-12);
    assert!((x[0] - 1.0).abs() < 1e-12 && (x[1] - 0.5).abs() < 1e-12);
}

#[test]
fn bad_inputs_return_err_without_panicking() {
    let n = 5;
    let a = Mat::<f64>::identity(n, n);
    let b = vec![1.0; n];
    let good = GmresParams::default();
    let mut ws = GmresWorkspace::new(n, good.restart);
    let mut x = vec![0.0; n];
    let id = Identity::new(n);

    let mismatch = |e: TimestepError, what: &str| match e {
        TimestepError::DimensionMismatch { what: w, .. } => assert!(w.contains(what), "{w}"),
        other => panic!("expected DimensionMismatch({what}), got {other:?}"),
    };
    mismatch(
        gmres(&a, &id, &b[..4], None, &mut x, &good, &mut ws).unwrap_err(),
        "b",
    );
    mismatch(
        gmres(&a, &id, &b, None, &mut x[..3], &good, &mut ws).unwrap_err(),
        "x",
    );
    mismatch(
        gmres(&a, &id, &b, Some(&[0.0; 2]), &mut x, &good, &mut ws).unwrap_err(),
        "x0",
    );
    mismatch(
        gmres(&a, &Identity::new(6), &b, None, &mut x, &good, &mut ws).unwrap_err(),
        "preconditioner",
    );
    let rect = Mat::<f64>::zeros(5, 4);
    assert!(matches!(
        gmres(&rect, &id, &b, None, &mut x, &good, &mut ws),
        Err(TimestepError::NotSquare { .. })
    ));
    for (p, name) in [
        (GmresParams { tol: 0.0, ..good }, "tol"),
        (GmresParams { tol: -1.0, ..good }, "tol"),
        (
            GmresParams {
                tol: f64::NAN,
                ..good
            },
            "tol",
        ),
        (GmresParams { restart: 0, ..good }, "restart"),
        (
            GmresParams {
                min_cycle_reduction: 1.0,
                ..good
            },
            "min_cycle_reduction",
        ),
        (
            GmresParams {
                min_cycle_reduction: -0.1,
                ..good
            },
            "min_cycle_reduction",
        ),
    ] {
        match gmres(&a, &id, &b, None, &mut x, &p, &mut ws) {
            Err(TimestepError::InvalidParameter { name: got, .. }) => assert_eq!(got, name),
            other => panic!("expected InvalidParameter({name}), got {other:?}"),
        }
    }
    let mut bad_b = b.clone();
    bad_b[2] = f64::NAN;
    assert!(matches!(
        gmres(&a, &id, &bad_b, None, &mut x, &good, &mut ws),
        Err(TimestepError::NonFinite { .. })
    ));
    assert!(matches!(
        gmres(
            &a,
            &id,
            &b,
            Some(&[f64::INFINITY; 5]),
            &mut x,
            &good,
            &mut ws
        ),
        Err(TimestepError::NonFinite { .. })
    ));
    // An operator that produces NaN.
    let nan_op = FnOperator::new(n, |_: &[f64], y: &mut [f64]| y.fill(f64::NAN));
    assert!(matches!(
        gmres(&nan_op, &id, &b, None, &mut x, &good, &mut ws),
        Err(TimestepError::NonFinite { .. })
    ));

    // Preconditioner construction.
    let nonsquare = Mat::<f64>::zeros(2, 3);
    assert!(matches!(
        BlockDiagonal::new(&[nonsquare.as_ref()]),
        Err(TimestepError::NotSquare { .. })
    ));
    let empty = Mat::<f64>::zeros(0, 0);
    assert!(matches!(
        BlockDiagonal::new(&[empty.as_ref()]),
        Err(TimestepError::NotSquare { .. })
    ));
    let singular = Mat::from_fn(3, 3, |i, j| (i + j) as f64); // rank 2
    let ok = Mat::<f64>::identity(2, 2);
    match BlockDiagonal::new(&[ok.as_ref(), singular.as_ref()]) {
        Err(TimestepError::SingularBlock { index, size, .. }) => {
            assert_eq!((index, size), (1, 3))
        }
        other => panic!("expected SingularBlock, got {other:?}"),
    }
    let mut nanblk = Mat::<f64>::identity(2, 2);
    nanblk[(0, 1)] = f64::NAN;
    assert!(matches!(
        BlockDiagonal::new(&[nanblk.as_ref()]),
        Err(TimestepError::NonFinite { .. })
    ));
    assert!(matches!(
        BlockDiagonal::from_diagonal_of(a.as_ref(), &[2, 2]),
        Err(TimestepError::DimensionMismatch { .. })
    ));
    assert!(matches!(
        BlockDiagonal::from_diagonal_of(rect.as_ref(), &[5]),
        Err(TimestepError::NotSquare { .. })
    ));
    // Every error has a message.
    let e = BlockDiagonal::new(&[singular.as_ref()]).unwrap_err();
    assert!(e.to_string().contains("singular"));
}

#[test]
fn zero_rhs_and_initial_guess() {
    let mut r = rng(9);
    let n = 80;
    let a = diag_dominant(&mut r, n);
    let params = GmresParams {
        tol: 1e-12,
        restart: 20,
        max_iters: 200,
        ..Default::default()
    };
    let mut ws = GmresWorkspace::new(n, params.restart);
    let id = Identity::new(n);
    // b = 0 → x = 0 whatever the guess, no iteration.
    let mut x = vec![0.0; n];
    let guess = random_vec(&mut r, n);
    let rep = gmres(
        &a,
        &id,
        &vec![0.0; n],
        Some(&guess),
        &mut x,
        &params,
        &mut ws,
    )
    .unwrap();
    assert_eq!(rep.iterations, 0);
    assert!(x.iter().all(|&v| v == 0.0));

    let b = random_vec(&mut r, n);
    let x_lu = lu_solve(&a, &b);
    // Exact guess: no iteration.
    let rep = gmres(&a, &id, &b, Some(&x_lu), &mut x, &params, &mut ws).unwrap();
    assert_eq!(rep.iterations, 0);
    assert!(rep.initial_relative_residual <= 1e-12);
    // A close guess needs fewer iterations than none.
    let cold = gmres(&a, &id, &b, None, &mut x, &params, &mut ws).unwrap();
    let near: Vec<f64> = x_lu
        .iter()
        .map(|v| v * (1.0 + 1e-6 * r.random_range(-1.0..1.0)))
        .collect();
    let warm = gmres(&a, &id, &b, Some(&near), &mut x, &params, &mut ws).unwrap();
    println!(
        "cold start {} iterations; guess at 1e-6: initial residual {:.1e}, {} iterations",
        cold.iterations, warm.initial_relative_residual, warm.iterations
    );
    assert!(warm.iterations < cold.iterations);
    assert!(rel_residual(&a, &x, &b) <= 1e-12);
}

#[test]
fn workspace_reuse_is_bit_identical() {
    let mut r = rng(10);
    let sizes = [20, 35, 25];
    let n: usize = sizes.iter().sum();
    let a = block_dominant(&mut r, &sizes, 0.3);
    let m = BlockDiagonal::from_diagonal_of(a.as_ref(), &sizes).unwrap();
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-12,
        restart: 8,
        max_iters: 500,
        ..Default::default()
    };
    let run = |ws: &mut GmresWorkspace| {
        let mut x = vec![0.0; n];
        let rep = gmres(&a, &m, &b, None, &mut x, &params, ws).unwrap();
        (x, rep)
    };
    let (x_fresh, rep_fresh) = run(&mut GmresWorkspace::new(n, params.restart));

    let mut ws = GmresWorkspace::new(n, params.restart);
    // Dirty the workspace with other solves: same size, other system; then another size.
    let other = diag_dominant(&mut r, n);
    let mut y = vec![0.0; n];
    gmres(
        &other,
        &Identity::new(n),
        &b,
        None,
        &mut y,
        &params,
        &mut ws,
    )
    .unwrap();
    let (x1, rep1) = run(&mut ws);
    let small = diag_dominant(&mut r, 17);
    let mut y = vec![0.0; 17];
    let p2 = GmresParams {
        restart: 3,
        ..params
    };
    gmres(
        &small,
        &Identity::new(17),
        &b[..17],
        None,
        &mut y,
        &p2,
        &mut ws,
    )
    .unwrap();
    assert_eq!(ws.size(), (17, 3));
    let (x2, rep2) = run(&mut ws);
    assert_eq!(ws.size(), (n, params.restart));
    println!(
        "{} iterations, {} restarts, residual {:.3e}",
        rep_fresh.iterations, rep_fresh.restarts, rep_fresh.relative_residual
    );
    assert!(rep_fresh.restarts > 0);
    for x in [&x1, &x2] {
        assert!(x
            .iter()
            .zip(&x_fresh)
            .all(|(u, v)| u.to_bits() == v.to_bits()));
    }
    assert_eq!(rep1, rep_fresh);
    assert_eq!(rep2, rep_fresh);
}

#[test]
fn no_allocation_inside_iterations() {
    // Allocations on this thread during a solve with a reused workspace: one (the report's
    // per-cycle residual list), whatever the number of iterations. The block preconditioner runs
    // in a one-thread rayon pool so that its work stays on the counted thread.
    let mut r = rng(11);
    let sizes = [30, 50, 40];
    let n: usize = sizes.iter().sum();
    let a = block_dominant(&mut r, &sizes, 0.3);
    let op = FnOperator::new(n, |x: &[f64], y: &mut [f64]| {
        for (i, yi) in y.iter_mut().enumerate() {
            let mut s = 0.0;
            for (j, xj) in x.iter().enumerate() {
                s += a[(i, j)] * xj;
            }
            *yi = s;
        }
    });
    let m = BlockDiagonal::from_diagonal_of(a.as_ref(), &sizes).unwrap();
    let b = random_vec(&mut r, n);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut counts = Vec::new();
    pool.install(|| {
        let mut ws = GmresWorkspace::new(n, 10);
        let mut x = vec![0.0; n];
        for tol in [1e-2, 1e-2, 1e-12] {
            for use_m in [false, true] {
                let params = GmresParams {
                    tol,
                    restart: 10,
                    max_iters: 2000,
                    ..Default::default()
                };
                let before = allocations();
                let rep = if use_m {
                    gmres(&op, &m, &b, None, &mut x, &params, &mut ws)
                } else {
                    gmres(&op, &Identity::new(n), &b, None, &mut x, &params, &mut ws)
                }
                .unwrap();
                let after = allocations();
                counts.push((tol, use_m, rep.iterations, after - before));
            }
        }
    });
    println!("(tol, preconditioned, iterations, allocations): {counts:?}");
    // The first pair may include one-time lazy initialisation; from then on one per solve.
    for &(_, _, _, allocs) in &counts[2..] {
        assert_eq!(allocs, 1);
    }
    assert!(counts[4].2 > 5 * counts[2].2.max(1));
}

#[test]
fn block_preconditioner_is_deterministic_across_thread_counts_and_matches_closure_jacobi() {
    // The blocks are applied in parallel, each independently, so the solve is bit-identical with
    // 1 and 4 rayon threads. With 1×1 blocks the block-diagonal preconditioner is Jacobi; a closure
    // z = v ./ diag(A) gives the same iterations and the same solution.
    let mut r = rng(12);
    let sizes = [25, 40, 10, 55, 30];
    let n: usize = sizes.iter().sum();
    let a = block_dominant(&mut r, &sizes, 0.3);
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-11,
        restart: 20,
        max_iters: 2000,
        ..Default::default()
    };
    let m = BlockDiagonal::from_diagonal_of(a.as_ref(), &sizes).unwrap();
    let run_in = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| solve(&a, &m, &b, &params))
    };
    let (x1, rep1) = run_in(1);
    let (x4, rep4) = run_in(4);
    assert_eq!(rep1.as_ref().unwrap(), rep4.as_ref().unwrap());
    assert!(x1.iter().zip(&x4).all(|(u, v)| u.to_bits() == v.to_bits()));

    let diag: Vec<f64> = (0..n).map(|i| a[(i, i)]).collect();
    let jacobi_blocks = BlockDiagonal::from_diagonal_of(a.as_ref(), &vec![1; n]).unwrap();
    let jacobi_fn = FnPreconditioner::new(n, |v: &[f64], z: &mut [f64]| {
        for ((zi, vi), di) in z.iter_mut().zip(v).zip(&diag) {
            *zi = vi / di;
        }
    });
    let (xb, rb) = solve(&a, &jacobi_blocks, &b, &params);
    let (xf, rf) = solve(&a, &jacobi_fn, &b, &params);
    let (rb, rf) = (rb.unwrap(), rf.unwrap());
    println!(
        "block-diagonal {} iterations; Jacobi as 1×1 blocks {} iterations, as closure {} \
         iterations; ‖x_blocks − x_closure‖/‖x‖ = {:.1e}",
        rep1.unwrap().iterations,
        rb.iterations,
        rf.iterations,
        rel_diff(&xb, &xf)
    );
    assert_eq!(rb.iterations, rf.iterations);
    assert!(rel_diff(&xb, &xf) < 1e-12);
}

/// An operator whose products carry errors of relative size ~1e-9 (as an FMM-coupled or
/// loosely assembled operator does) cannot be solved to 1e-12: the recurrence's residual
/// estimate meets the tolerance while the true residual stays near 1e-9, and every cycle ends
/// early. Such short cycles without progress are stagnation: the solve stops after a few,
/// with the residual history, instead of grinding to `max_iters`.
#[test]
fn short_cycles_at_the_attainable_accuracy_floor_are_stagnation() {
    struct Noisy {
        a: Vec<f64>,
        n: usize,
        calls: std::sync::atomic::AtomicU64,
    }
    impl LinearOperator for Noisy {
        fn nrows(&self) -> usize {
            self.n
        }
        fn ncols(&self) -> usize {
            self.n
        }
        fn apply(&self, x: &[f64], y: &mut [f64]) {
            let c = self
                .calls
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let scale = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            for (i, yi) in y.iter_mut().enumerate() {
                let row = &self.a[i * self.n..(i + 1) * self.n];
                let exact: f64 = row.iter().zip(x).map(|(a, x)| a * x).sum();
                // A deterministic perturbation, different at every call, of relative size 1e-9.
                let h = ((c * 7919 + i as u64 * 104_729) % 1000) as f64 / 1000.0 - 0.5;
                *yi = exact + 2e-9 * h * scale;
            }
        }
    }
    let n = 60;
    let mut r = rng(21);
    // Well conditioned: identity plus a small random part.
    let mut a = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            a[i * n + j] = 0.3 * (r.random::<f64>() - 0.5) / (n as f64).sqrt();
        }
        a[i * n + i] += 1.0;
    }
    let op = Noisy {
        a,
        n,
        calls: std::sync::atomic::AtomicU64::new(0),
    };
    let b = random_vec(&mut r, n);
    let params = GmresParams {
        tol: 1e-13,
        restart: 30,
        max_iters: 5000,
        ..Default::default()
    };
    let (_, res) = solve(&op, &Identity::new(n), &b, &params);
    let err = res.unwrap_err();
    println!("noisy operator to 1e-13: {err}");
    let TimestepError::Stagnated(rep) = &err else {
        panic!("expected Stagnated, got {err:?}");
    };
    assert!(
        rep.iterations < 300,
        "ground on for {} iterations",
        rep.iterations
    );
    assert!(
        rep.relative_residual > 1e-13 && rep.relative_residual < 1e-7,
        "{}",
        rep.relative_residual
    );
    // The same operator to a tolerance above its floor converges.
    let params = GmresParams {
        tol: 1e-7,
        ..params
    };
    let (_, res) = solve(&op, &Identity::new(n), &b, &params);
    assert!(res.is_ok(), "{res:?}");
}
