//! The FMM over MPI ranks gives the one-rank answer: for K = 1, 2, 3, 4 ranks
//! (`mpirun --allow-run-as-root --oversubscribe`), every kernel on the clouds of
//! `fmm::clouds` (uniform, blobs, cell-like spheres, one tight cluster) at 3, 6 and 9 digits,
//! each rank holding a scattered share of the points: the gathered K-rank result equals the
//! one-rank result to 1e-12 relative, and both equal direct sums to the requested digits.
//! New densities on the same tree, separate targets, and a rank with bad input (every rank
//! gets one error naming that rank; none hangs) are covered too.
//!
//! A `harness = false` test: run without arguments it launches itself under `mpirun` once per
//! K (needs `mpirun` on the PATH: Debian's `openmpi-bin`); under `mpirun` (MOBO_MPI_CHILD set)
//! it is one rank of the check.

use std::process::Command;

use mobo::comm::{Communicator, MpiComm};
use mobo::fmm::clouds::Cloud;
use mobo::fmm::{direct_sum, order_for_digits, Fmm, FmmError, FmmKernel, SumInput};

const KERNELS: [FmmKernel; 5] = [
    FmmKernel::Laplace,
    FmmKernel::LaplaceDoubleLayer,
    FmmKernel::Stokeslet,
    FmmKernel::Stresslet,
    FmmKernel::Rpy { radius: 0.004 },
];
const CLOUDS: [Cloud; 4] = [
    Cloud::Uniform,
    Cloud::Blobs,
    Cloud::Spheres,
    Cloud::Clustered,
];
const N: usize = 2400;
const LEAF: usize = 40;

/// Which rank holds global point `i` (scattered: every rank's points are all over space).
fn holder(i: usize, k: usize) -> usize {
    (i * 7919 + 13) % k
}

fn rel(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

/// This rank's share of a global array of `dim`-vectors.
fn share<T: Copy>(all: &[T], dim: usize, comm: &dyn Communicator) -> Vec<T> {
    (0..all.len() / dim)
        .filter(|&i| holder(i, comm.size()) == comm.rank())
        .flat_map(|i| all[i * dim..(i + 1) * dim].iter().copied())
        .collect()
}

/// Gather every rank's values (its own targets, in its order) into the global order.
fn gather(comm: &dyn Communicator, mine: &[f64], n: usize, dim: usize) -> Vec<f64> {
    let all = comm.all_gather_f64(mine).unwrap();
    let mut out = vec![0.0; n * dim];
    let mut next = vec![0usize; comm.size()];
    for i in 0..n {
        let r = holder(i, comm.size());
        out[i * dim..(i + 1) * dim].copy_from_slice(&all[r][next[r] * dim..(next[r] + 1) * dim]);
        next[r] += 1;
    }
    out
}

struct Case {
    kernel: FmmKernel,
    cloud: Cloud,
    digits: u32,
    separate_targets: bool,
}

/// One case on all ranks; rank 0 returns its failures.
fn run_case(comm: &dyn Communicator, c: &Case) -> Vec<String> {
    let near = c.kernel.near();
    let (ds, dt) = (near.density_dim(), near.output_dim());
    let src = c.cloud.points(N, 3);
    let nrm = Cloud::unit_vectors(N, 4);
    let tgt = if c.separate_targets {
        Cloud::Uniform.points(N / 2, 5)
    } else {
        src.clone()
    };
    let order = order_for_digits(c.kernel, c.digits).unwrap();
    let needs_n = near.needs_normals();
    let my_src = share(&src, 1, comm);
    let my_nrm = share(&nrm, 1, comm);
    let my_tgt = share(&tgt, 1, comm);
    let mut fmm = Fmm::new_on(
        comm,
        c.kernel,
        &my_src,
        needs_n.then_some(&my_nrm[..]),
        &my_tgt,
        order,
        LEAF,
    )
    .unwrap();
    let mut fails = Vec::new();
    for round in 0..2u64 {
        let dens = Cloud::densities(N * ds, 10 + round);
        let my_dens = share(&dens, ds, comm);
        let mut mine = vec![0.0; my_tgt.len() * dt];
        fmm.evaluate_on(comm, &my_dens, &mut mine).unwrap();
        let got = gather(comm, &mine, tgt.len(), dt);
        if comm.rank() != 0 {
            continue;
        }
        let mut one = Fmm::new(
            c.kernel,
            &src,
            needs_n.then_some(&nrm[..]),
            &tgt,
            order,
            LEAF,
        )
        .unwrap();
        let mut want = vec![0.0; tgt.len() * dt];
        one.evaluate(&dens, &mut want).unwrap();
        let e_ranks = rel(&got, &want);
        let same_bits = got
            .iter()
            .zip(&want)
            .filter(|(a, b)| a.to_bits() == b.to_bits())
            .count();
        // Direct sums at sampled targets.
        let idx: Vec<usize> = (0..150).map(|i| i * tgt.len() / 150).collect();
        let sample: Vec<[f64; 3]> = idx.iter().map(|&i| tgt[i]).collect();
        let mut exact = vec![0.0; idx.len() * dt];
        let input = SumInput {
            sources: &src,
            density: &dens,
            normals: Some(&nrm),
            targets: &sample,
        };
        direct_sum(near.as_ref(), &input, &mut exact).unwrap();
        let got_s: Vec<f64> = idx
            .iter()
            .flat_map(|&i| got[i * dt..(i + 1) * dt].iter().copied())
            .collect();
        let e_direct = rel(&got_s, &exact);
        let name = format!(
            "{:?} {} digits={} order={order}{} round {round} K={}",
            c.kernel,
            c.cloud.name(),
            c.digits,
            if c.separate_targets {
                " separate targets"
            } else {
                ""
            },
            comm.size()
        );
        println!(
            "{name}: depth {} | K vs 1 rank {e_ranks:.1e} ({same_bits}/{} bit-identical) | vs direct {e_direct:.1e}",
            one.tree.depth(),
            got.len()
        );
        if !(e_ranks <= 1e-12) {
            fails.push(format!("{name}: K-rank vs 1-rank {e_ranks:.2e}"));
        }
        if !(e_direct < 10f64.powi(-(c.digits as i32))) {
            fails.push(format!("{name}: vs direct {e_direct:.2e}"));
        }
    }
    fails
}

/// One rank passes densities of the wrong length: every rank must return an error naming it.
fn bad_rank(comm: &dyn Communicator) -> Vec<String> {
    let src = Cloud::Uniform.points(500, 1);
    let mine = share(&src, 1, comm);
    let mut fmm = Fmm::new_on(comm, FmmKernel::Laplace, &mine, None, &mine, 4, LEAF).unwrap();
    let bad = comm.size() - 1;
    let n = if comm.rank() == bad {
        mine.len() + 1
    } else {
        mine.len()
    };
    let mut out = vec![0.0; mine.len()];
    match fmm.evaluate_on(comm, &vec![1.0; n], &mut out) {
        Err(FmmError::Comm(e)) if comm.size() > 1 => {
            let msg = e.to_string();
            if msg.contains(&format!("rank {bad}")) && msg.contains("density has") {
                vec![]
            } else {
                vec![format!("bad rank: unexpected message '{msg}'")]
            }
        }
        Err(FmmError::Shape(m)) if comm.size() == 1 && m.contains("density has") => vec![],
        other => vec![format!(
            "bad rank: expected an error, got {:?}",
            other.err()
        )],
    }
}

fn child() -> i32 {
    let comm = MpiComm::init().expect("MPI initialised once");
    let mut fails = Vec::new();
    let digits_list: Vec<u32> = std::env::var("MOBO_MPI_DIGITS")
        .unwrap_or_else(|_| "3,6,9".into())
        .split(',')
        .filter_map(|d| d.trim().parse().ok())
        .collect();
    for digits in digits_list {
        for kernel in KERNELS {
            for cloud in CLOUDS {
                let case = Case {
                    kernel,
                    cloud,
                    digits,
                    separate_targets: false,
                };
                fails.extend(run_case(&comm, &case));
            }
        }
    }
    for kernel in [FmmKernel::Laplace, FmmKernel::Stokeslet] {
        let case = Case {
            kernel,
            cloud: Cloud::Clustered,
            digits: 6,
            separate_targets: true,
        };
        fails.extend(run_case(&comm, &case));
    }
    fails.extend(bad_rank(&comm));
    for f in &fails {
        eprintln!("rank {}: FAILED {f}", comm.rank());
    }
    let fails = comm.all_gather_u64(&[fails.len() as u64]).unwrap();
    let total: u64 = fails.iter().map(|v| v[0]).sum();
    i32::from(total > 0)
}

fn main() {
    if std::env::var_os("MOBO_MPI_CHILD").is_some() {
        let code = child();
        std::process::exit(code);
    }
    let exe = std::env::current_exe().expect("test binary path");
    let mut failed = Vec::new();
    for k in 1..=4 {
        println!("== mpirun -n {k}");
        let status = Command::new("mpirun")
            .args([
                "--allow-run-as-root",
                "--oversubscribe",
                "-n",
                &k.to_string(),
            ])
            .arg(&exe)
            .env("MOBO_MPI_CHILD", "1")
            .env("RAYON_NUM_THREADS", "1")
            .status();
        match status {
            Ok(s) if s.success() => {}
            Ok(s) => failed.push(format!("K = {k}: {s}")),
            Err(e) => failed.push(format!(
                "K = {k}: cannot run mpirun ({e}); install openmpi-bin"
            )),
        }
    }
    if !failed.is_empty() {
        eprintln!("mpi_fmm failed: {failed:?}");
        std::process::exit(1);
    }
    println!("mpi_fmm: K = 1..4 agree with one rank and with direct sums");
}
