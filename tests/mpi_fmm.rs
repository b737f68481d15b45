//! The FMM over MPI ranks gives the one-rank answer: for K = 1, 2, 3, 4 ranks
//! (`mpirun --allow-run-as-root --oversubscribe`), every kernel on the clouds of
//! `fmm::clouds` (uniform, blobs, cell-like spheres, one tight cluster) at 3, 6 and 9 digits,
//! each rank holding a scattered share of the points: the gathered K-rank result equals the
//! one-rank result to 1e-12 relative, and both equal direct sums to the requested digits.
//! New densities on the same tree (at 3 digits), separate targets, a rank with bad input
//! (every rank gets one error naming that rank; none hangs), the cuts of the key line between
//! ranks (equal point counts to 0.5 % and a leaf, whatever rank the points start on), and `mpirun -n K mobo fmm` (the same file for K = 1 and 3; a NaN in one rank's rows stops
//! all with one message) too.
//!
//! K = 1 runs first: it also evaluates with `Fmm::new` (no MPI), checks that both agree, and
//! keeps that result as the reference of K = 2, 3, 4. The fits of the translation operators
//! are computed once and shared through `MOBO_OPERATOR_CACHE` (default: the test's tmp dir).
//! `MOBO_MPI_KS` and `MOBO_MPI_DIGITS` (e.g. `1,2` and `9`) run a part.
//!
//! A `harness = false` test: run without arguments it launches itself under `mpirun` once per
//! K (needs `mpirun` on the PATH: Debian's `openmpi-bin`); under `mpirun` (MOBO_MPI_CHILD set)
//! it is one rank of the check.

use std::path::{Path, PathBuf};
use std::process::Command;

use mobo::comm::{Communicator, MpiComm};
use mobo::fmm::clouds::Cloud;
use mobo::fmm::{
    clear_operator_cache, direct_sum, order_for_digits, Fmm, FmmError, FmmKernel, SumInput,
};
use mobo::io::npy;

/// The kernels, with whether the next one has other translation operators (Laplace SL and
/// DL share Laplace's, Stokeslet and RPY the Stokeslet's).
const KERNELS: [(FmmKernel, bool); 5] = [
    (FmmKernel::Laplace, false),
    (FmmKernel::LaplaceDoubleLayer, true),
    (FmmKernel::Stokeslet, false),
    (FmmKernel::Rpy { radius: 0.004 }, true),
    (FmmKernel::Stresslet, true),
];
const CLOUDS: [Cloud; 4] = [
    Cloud::Uniform,
    Cloud::Blobs,
    Cloud::Spheres,
    Cloud::Clustered,
];
const N: usize = 2400;

/// Which rank holds global point `i` (scattered: every rank's points are all over space).
fn holder(i: usize, k: usize) -> usize {
    (i * 7919 + 13) % k
}

/// `x ≤ tol`, false for NaN.
fn at_most(x: f64, tol: f64) -> bool {
    x <= tol
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

impl Case {
    fn name(&self) -> String {
        format!(
            "{:?} {} digits={}{}",
            self.kernel,
            self.cloud.name(),
            self.digits,
            if self.separate_targets {
                " separate-targets"
            } else {
                ""
            }
        )
    }
}

/// Where the one-rank results of the K = 1 run are kept for the runs with more ranks.
fn reference_file(c: &Case, round: u64) -> PathBuf {
    let dir = PathBuf::from(std::env::var("MOBO_MPI_REFS").expect("set by the parent"));
    let name: String = c
        .name()
        .chars()
        .map(|ch| if ch.is_ascii_alphanumeric() { ch } else { '_' })
        .collect();
    dir.join(format!("{name}-{round}.bin"))
}

fn to_bytes(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn from_bytes(b: &[u8]) -> Vec<f64> {
    b.chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// Leaf size: small enough that every rank holds several leaves, growing with the order as
/// the default does (`100·order`) so that high orders are not spent on tiny leaves.
fn leaf_for(order: usize) -> usize {
    10 * order
}

/// One case on all ranks; rank 0 returns its failures. With one rank (the first run) it also
/// evaluates with [`Fmm::new`] (no MPI at all), checks both agree, and stores the result as
/// the reference of the runs with more ranks.
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
    let leaf = leaf_for(order);
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
        leaf,
    )
    .unwrap();
    let mut fails = Vec::new();
    let name = format!("{} order={order} leaf={leaf} K={}", c.name(), comm.size());
    let t0 = std::time::Instant::now();
    // New densities on the same tree (a second round) at the cheapest accuracy.
    let rounds = if c.digits == 3 { 2 } else { 1 };
    for round in 0..rounds {
        let dens = Cloud::densities(N * ds, 10 + round);
        let my_dens = share(&dens, ds, comm);
        let mut mine = vec![0.0; my_tgt.len() * dt];
        fmm.evaluate_on(comm, &my_dens, &mut mine).unwrap();
        let got = gather(comm, &mine, tgt.len(), dt);
        if comm.rank() != 0 {
            continue;
        }
        let file = reference_file(c, round);
        let (want, depth) = if comm.size() == 1 {
            let mut one = Fmm::new(
                c.kernel,
                &src,
                needs_n.then_some(&nrm[..]),
                &tgt,
                order,
                leaf,
            )
            .unwrap();
            let mut want = vec![0.0; tgt.len() * dt];
            one.evaluate(&dens, &mut want).unwrap();
            std::fs::write(&file, to_bytes(&want)).unwrap();
            if one.tree.depth() < 3 {
                fails.push(format!(
                    "{name}: tree of depth {} has no far field",
                    one.tree.depth()
                ));
            }
            (want, one.tree.depth())
        } else {
            match std::fs::read(&file) {
                Ok(b) => (from_bytes(&b), fmm.tree.depth()),
                Err(e) => {
                    fails.push(format!(
                        "{name}: no one-rank reference {}: {e}",
                        file.display()
                    ));
                    continue;
                }
            }
        };
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
        println!(
            "{name} round {round} ({:.1} s): depth {depth} | vs 1 rank {e_ranks:.1e} ({same_bits}/{} bit-identical) | vs direct {e_direct:.1e}",
            t0.elapsed().as_secs_f64(),
            got.len()
        );
        if !at_most(e_ranks, 1e-12) || got.len() != want.len() {
            fails.push(format!(
                "{name} round {round}: K-rank vs 1-rank {e_ranks:.2e}"
            ));
        }
        if !at_most(e_direct, 10f64.powi(-(c.digits as i32))) {
            fails.push(format!("{name} round {round}: vs direct {e_direct:.2e}"));
        }
    }
    fails
}

/// One rank passes densities of the wrong length: every rank must return an error naming it.
fn bad_rank(comm: &dyn Communicator) -> Vec<String> {
    let src = Cloud::Uniform.points(500, 1);
    let mine = share(&src, 1, comm);
    let mut fmm = Fmm::new_on(comm, FmmKernel::Laplace, &mine, None, &mine, 4, 40).unwrap();
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

/// The cuts between ranks (`fmm::splitters`, a selection by histograms), on the cell-like
/// cloud (Laplace, 6 digits): whether the points come scattered over the ranks, in pieces of
/// the curve of uneven length (1.2 : 1), or all on the last rank, every rank ends up with
/// `N/K` points (sources and targets) to within the selection's 0.5 % and one leaf per cut
/// (the cuts move to leaf boundaries); the pieces move no points but those of the leaves the
/// cuts fall in and those of the uneven pieces' excess; and the answer is one rank's to 1e-12.
fn partition_checks(comm: &dyn Communicator) -> Vec<String> {
    let (k, me) = (comm.size(), comm.rank());
    let kernel = FmmKernel::Laplace;
    let pts = Cloud::Spheres.points(N, 7);
    let dens = Cloud::densities(N, 8);
    let order = order_for_digits(kernel, 6).unwrap();
    let leaf = leaf_for(order);
    let mut one = Fmm::new(kernel, &pts, None, &pts, order, leaf).unwrap();
    let mut want = vec![0.0; N];
    one.evaluate(&dens, &mut want).unwrap();
    // Contiguous pieces of the tree's curve, rank r's piece 1.2 times as long for odd r.
    let mut by_key: Vec<usize> = (0..N).collect();
    by_key.sort_by_key(|&i| (one.tree.domain.key(pts[i]), i));
    let weight = |r: usize| if r % 2 == 1 { 1.2 } else { 1.0 };
    let total: f64 = (0..k).map(weight).sum();
    let mut piece = vec![0usize; N];
    let mut at = 0.0;
    for r in 0..k {
        let (a, b) = (at, at + weight(r) / total * N as f64);
        for &i in &by_key[a.round() as usize..(b.round() as usize).min(N)] {
            piece[i] = r;
        }
        at = b;
    }
    // Points a piece holds beyond its share.
    let excess: f64 = (0..k)
        .map(|r| (weight(r) / total - 1.0 / k as f64).max(0.0) * N as f64)
        .sum();
    let scattered: Vec<usize> = (0..N).map(|i| holder(i, k)).collect();
    let last = vec![k - 1; N];
    let mut fails = Vec::new();
    for (name, holders) in [
        ("scattered", &scattered),
        ("pieces", &piece),
        ("all on the last rank", &last),
    ] {
        let mine: Vec<usize> = (0..N).filter(|&i| holders[i] == me).collect();
        let my_pts: Vec<[f64; 3]> = mine.iter().map(|&i| pts[i]).collect();
        let my_dens: Vec<f64> = mine.iter().map(|&i| dens[i]).collect();
        let mut fmm = Fmm::new_on(comm, kernel, &my_pts, None, &my_pts, order, leaf).unwrap();
        let mut u = vec![0.0; mine.len()];
        fmm.evaluate_on(comm, &my_dens, &mut u).unwrap();
        // Into the global order.
        let ids: Vec<f64> = mine.iter().map(|&i| i as f64).collect();
        let (all_ids, all_u) = (
            comm.all_gather_f64(&ids).unwrap(),
            comm.all_gather_f64(&u).unwrap(),
        );
        let mut got = vec![f64::NAN; N];
        for (ids, vals) in all_ids.iter().zip(&all_u) {
            for (&i, &v) in ids.iter().zip(vals) {
                got[i as usize] = v;
            }
        }
        let e = rel(&got, &want);
        let load = (fmm.tree.n_owned_sources + fmm.tree.targets.len()) as f64;
        let moved = fmm.tree.points_moved() as f64;
        let loads = comm.all_gather_f64(&[load, moved]).unwrap();
        // Sources and targets are the same points: both count.
        let mean = 2.0 * N as f64 / k as f64;
        let worst = loads
            .iter()
            .map(|l| (l[0] - mean).abs())
            .fold(0.0, f64::max);
        let moved_all: f64 = loads.iter().map(|l| l[1]).sum();
        if me == 0 {
            println!(
                "cuts K={k} {name}: vs 1 rank {e:.1e}, loads {:?}, points moved {moved_all}",
                loads.iter().map(|l| l[0]).collect::<Vec<_>>()
            );
        }
        if !at_most(e, 1e-12) {
            fails.push(format!("cuts {name}: K-rank vs 1-rank {e:.2e}"));
        }
        let bound = 2.0 * (mean / 200.0 + 1.0 + leaf as f64);
        if worst > bound {
            fails.push(format!(
                "cuts {name}: a rank's load is {worst} off the mean {mean} (bound {bound})"
            ));
        }
        let moved_bound = 2.0 * excess + ((k - 1) * (leaf + 1)) as f64 + k as f64 * bound;
        if name == "pieces" && moved_all > moved_bound {
            fails.push(format!(
                "cuts {name}: {moved_all} points moved, more than {moved_bound}"
            ));
        }
    }
    fails
}

/// A comma-separated list from the environment variable `name`, or from `default`.
fn env_list<T: std::str::FromStr>(name: &str, default: &str) -> Vec<T> {
    std::env::var(name)
        .unwrap_or_else(|_| default.into())
        .split(',')
        .filter_map(|v| v.trim().parse().ok())
        .collect()
}

fn child() -> i32 {
    let comm = MpiComm::init().expect("MPI initialised once");
    let mut fails = Vec::new();
    for digits in env_list::<u32>("MOBO_MPI_DIGITS", "3,6,9") {
        for (kernel, last_of_its_operators) in KERNELS {
            for cloud in CLOUDS {
                let case = Case {
                    kernel,
                    cloud,
                    digits,
                    separate_targets: false,
                };
                fails.extend(run_case(&comm, &case));
            }
            // Keep one kernel's operators at a time (order 15: 3.5 GB per rank).
            if last_of_its_operators {
                clear_operator_cache();
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
    fails.extend(partition_checks(&comm));
    for f in &fails {
        eprintln!("rank {}: FAILED {f}", comm.rank());
    }
    let fails = comm.all_gather_u64(&[fails.len() as u64]).unwrap();
    let total: u64 = fails.iter().map(|v| v[0]).sum();
    i32::from(total > 0)
}

fn mpirun(k: usize) -> Command {
    let mut c = Command::new("mpirun");
    c.args([
        "--allow-run-as-root",
        "--oversubscribe",
        "-n",
        &k.to_string(),
    ])
    // One thread per rank when ranks share the two cores; both when alone.
    .env("RAYON_NUM_THREADS", if k == 1 { "2" } else { "1" })
    // Containers often forbid the cross-memory attach of OpenMPI's shared-memory transport.
    .env("OMPI_MCA_btl_vader_single_copy_mechanism", "none");
    c
}

/// `mpirun -n K mobo fmm`: the result file for K = 3 equals K = 1's, the JSON line reports
/// every rank, and a non-finite value in one rank's rows stops every rank with one message.
fn cli_checks(dir: &Path) -> Vec<String> {
    let mut fails = Vec::new();
    let n = 3000;
    let src = Cloud::Spheres.points(n, 21);
    let flat: Vec<f64> = src.iter().flatten().copied().collect();
    let dens = Cloud::densities(3 * n, 22);
    let (s_path, f_path) = (dir.join("src.npy"), dir.join("f.npy"));
    npy::write_f64(&s_path, &[n, 3], &flat).unwrap();
    npy::write_f64(&f_path, &[n, 3], &dens).unwrap();
    let run = |k: usize, density: &Path, out: &Path| {
        mpirun(k)
            .arg(env!("CARGO_BIN_EXE_mobo"))
            .args([
                "fmm",
                "--kernel",
                "stokeslet",
                "--digits",
                "6",
                "--leaf-size",
                "100",
            ])
            .arg("--sources")
            .arg(&s_path)
            .arg("--density")
            .arg(density)
            .arg("--out")
            .arg(out)
            .output()
            .expect("mpirun runs")
    };
    let mut outs = Vec::new();
    for k in [1, 3] {
        let out = dir.join(format!("u{k}.npy"));
        let o = run(k, &f_path, &out);
        let stdout = String::from_utf8_lossy(&o.stdout).to_string();
        println!("mobo fmm on {k} ranks: {}", stdout.trim());
        if !o.status.success() {
            fails.push(format!(
                "mobo fmm on {k} ranks failed: {}",
                String::from_utf8_lossy(&o.stderr)
            ));
            return fails;
        }
        let json: serde_json::Value = match serde_json::from_str(stdout.trim()) {
            Ok(j) => j,
            Err(e) => {
                fails.push(format!(
                    "{k} ranks: stdout is not one JSON line ({e}): {stdout}"
                ));
                return fails;
            }
        };
        let counts: Vec<u64> = json["rank_sources"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_u64()).collect())
            .unwrap_or_default();
        let bytes = json["rank_bytes_sent"].as_array().map_or(0, |a| a.len());
        if json["ranks"] != k || counts.len() != k || counts.iter().sum::<u64>() != n as u64 {
            fails.push(format!("{k} ranks: JSON line reports {json}"));
        }
        if bytes != k || json["load_imbalance"].as_f64().is_none_or(|v| v < 1.0) {
            fails.push(format!(
                "{k} ranks: no per-rank bytes or imbalance in {json}"
            ));
        }
        outs.push(npy::read_f64(&out).unwrap().1);
    }
    let e = rel(&outs[1], &outs[0]);
    println!("mobo fmm: 3 ranks vs 1 rank {e:.1e}");
    if !at_most(e, 1e-12) {
        fails.push(format!("mobo fmm: 3 ranks differ from 1 rank by {e:.2e}"));
    }
    // A NaN in the last rank's rows: every rank stops, one message names the file and row.
    let mut bad = dens.clone();
    bad[3 * (n - 10) + 1] = f64::NAN;
    let bad_path = dir.join("bad.npy");
    npy::write_f64(&bad_path, &[n, 3], &bad).unwrap();
    let o = run(3, &bad_path, &dir.join("never.npy"));
    let err = String::from_utf8_lossy(&o.stderr);
    let mentions = err.matches("non-finite").count();
    println!(
        "mobo fmm with a NaN on rank 2: {} | {}",
        o.status,
        err.trim()
    );
    if o.status.success()
        || mentions != 1
        || !err.contains("bad.npy")
        || !err.contains(&format!("row {}", n - 10))
    {
        fails.push(format!(
            "NaN on one rank: expected one message naming bad.npy and row {} and a non-zero exit, got {} and '{err}'",
            n - 10,
            o.status
        ));
    }
    if dir.join("never.npy").exists() {
        fails.push("NaN on one rank: an output file was written".into());
    }
    fails
}

fn main() {
    if std::env::var_os("MOBO_MPI_CHILD").is_some() {
        let code = child();
        std::process::exit(code);
    }
    let tmp = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let refs = tmp.join(format!("mpi_fmm-{}", std::process::id()));
    std::fs::create_dir_all(&refs).unwrap();
    // The fits are computed once (K = 1) and read by the other runs' ranks.
    let cache = std::env::var_os("MOBO_OPERATOR_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| tmp.join("operator-cache"));
    let exe = std::env::current_exe().expect("test binary path");
    let mut failed = Vec::new();
    // MOBO_MPI_KS=1,2 runs fewer rank counts (K = 1 must come first: it writes the references).
    let ks = env_list::<usize>("MOBO_MPI_KS", "1,2,3,4");
    for &k in &ks {
        let t0 = std::time::Instant::now();
        println!("== mpirun -n {k}");
        let status = mpirun(k)
            .arg(&exe)
            .env("MOBO_MPI_CHILD", "1")
            .env("MOBO_MPI_REFS", &refs)
            .env("MOBO_OPERATOR_CACHE", &cache)
            .status();
        match status {
            Ok(s) if s.success() => println!("== K = {k}: {:.0} s", t0.elapsed().as_secs_f64()),
            Ok(s) => failed.push(format!("K = {k}: {s}")),
            Err(e) => {
                failed.push(format!(
                    "K = {k}: cannot run mpirun ({e}); install openmpi-bin"
                ));
                break;
            }
        }
    }
    if failed.is_empty() {
        failed.extend(cli_checks(&refs));
    }
    let _ = std::fs::remove_dir_all(&refs);
    if !failed.is_empty() {
        eprintln!("mpi_fmm failed: {failed:#?}");
        std::process::exit(1);
    }
    println!("mpi_fmm: K = {ks:?} agree with one rank and with direct sums; mobo fmm under mpirun");
}
