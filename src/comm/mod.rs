//! The communicator seam: what the distributed algorithms need from a set of ranks.
//!
//! One code path serves one rank and `K` ranks: the FMM (and later the cells) are written
//! against [`Communicator`], and a run on one process uses [`SerialComm`], which needs no MPI
//! and whose collectives are copies. With the `mpi` feature, [`MpiComm`] implements the same
//! trait over `MPI_COMM_WORLD` (rsmpi). The serial implementation is the reference: every
//! distributed result is tested against a one-rank run of the same code.
//!
//! The operations are the few the algorithms use, on `f64` and `u64` buffers:
//! reductions of small vectors (the global domain, counts), all-gathers of small per-rank
//! records (splitter samples, the top of the tree), all-to-alls (the partition of points,
//! which every point crosses once) and point-to-point exchanges with a known set of partners
//! and sizes (the locally essential tree: only neighbouring ranks). Every byte sent to another
//! rank is counted ([`Communicator::bytes_sent`]).
//!
//! ```
//! use mobo::comm::{Communicator, SerialComm};
//! let comm = SerialComm;
//! let mut v = [3.0, -1.0];
//! comm.all_min(&mut v).unwrap();
//! assert_eq!((comm.rank(), comm.size(), v), (0, 1, [3.0, -1.0]));
//! assert_eq!(comm.all_gather_u64(&[7, 8]).unwrap(), vec![vec![7, 8]]);
//! ```
// Without the feature `MpiComm` does not exist: the link above cannot resolve.
#![cfg_attr(not(feature = "mpi"), allow(rustdoc::broken_intra_doc_links))]

#[cfg(feature = "mpi")]
mod mpi_comm;
#[cfg(feature = "mpi")]
pub use mpi_comm::MpiComm;

/// Errors of communication.
#[derive(Clone, Debug, thiserror::Error, PartialEq, Eq)]
pub enum CommError {
    /// A buffer whose length does not fit the number of ranks.
    #[error("communicator: {what} has {got} entries for {ranks} ranks")]
    Ranks {
        /// The buffer, in words.
        what: &'static str,
        /// Its length (entries, or per-rank buffers).
        got: usize,
        /// Number of ranks.
        ranks: usize,
    },
    /// A rank named that does not exist.
    #[error("communicator: rank {rank} does not exist ({ranks} ranks)")]
    NoSuchRank {
        /// The rank named.
        rank: usize,
        /// Number of ranks.
        ranks: usize,
    },
    /// A message too long for MPI's 32-bit counts.
    #[error("communicator: a message of {0} values exceeds MPI's count limit")]
    TooLong(usize),
    /// Two ranks disagree about what one sends the other (a bug, caught before it can hang).
    #[error("communicator: ranks disagree: {0}")]
    Disagree(String),
    /// Another rank failed; its message, agreed by every rank.
    #[error("rank {rank}: {message}")]
    Remote {
        /// The lowest failing rank.
        rank: usize,
        /// Its error message.
        message: String,
    },
}

/// The collective and point-to-point operations of the distributed algorithms. All ranks
/// call the collectives in the same order (MPI's rule); buffers are per rank where a
/// `Vec<Vec<_>>` is taken or returned (entry `r` goes to or came from rank `r`).
pub trait Communicator {
    /// This process's rank, `0..size()`.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn size(&self) -> usize;
    /// Element-wise minimum over ranks, in place.
    fn all_min(&self, v: &mut [f64]) -> Result<(), CommError>;
    /// Element-wise maximum over ranks, in place.
    fn all_max(&self, v: &mut [f64]) -> Result<(), CommError>;
    /// Element-wise sum over ranks, in place (exact: integers).
    fn all_sum_u64(&self, v: &mut [u64]) -> Result<(), CommError>;
    /// Every rank's `local`, indexed by rank.
    fn all_gather_u64(&self, local: &[u64]) -> Result<Vec<Vec<u64>>, CommError>;
    /// Every rank's `local`, indexed by rank.
    fn all_gather_f64(&self, local: &[f64]) -> Result<Vec<Vec<f64>>, CommError>;
    /// Every rank's `local` at rank `root`, indexed by rank (empty on the other ranks).
    fn gather_f64(&self, local: &[f64], root: usize) -> Result<Vec<Vec<f64>>, CommError>;
    /// Personalised all-to-all: `send[r]` goes to rank `r`; returns what each rank sent here.
    fn all_to_all_u64(&self, send: &[Vec<u64>]) -> Result<Vec<Vec<u64>>, CommError>;
    /// Personalised all-to-all of `f64` buffers.
    fn all_to_all_f64(&self, send: &[Vec<f64>]) -> Result<Vec<Vec<f64>>, CommError>;
    /// Point-to-point exchange with known partners: `sends` are `(rank, buffer)`, `recvs` are
    /// `(rank, length)`; returns the received buffers in the order of `recvs`.
    fn exchange_f64(
        &self,
        sends: &[(usize, &[f64])],
        recvs: &[(usize, usize)],
    ) -> Result<Vec<Vec<f64>>, CommError>;
    /// Bytes this rank has sent to other ranks so far.
    fn bytes_sent(&self) -> u64;
    /// Messages this rank has sent to other ranks so far (a collective counts one message to
    /// each other rank it sends to, as a LogGP model charges it; 0 on one process).
    fn messages_sent(&self) -> u64 {
        0
    }

    /// Agree on success: every rank passes its own outcome; if any rank failed, every rank
    /// returns the error of the lowest failing rank (so all exit with one message, none hangs).
    fn agree(&self, local: Result<(), String>) -> Result<(), CommError> {
        let bytes: Vec<u64> = match &local {
            Ok(()) => Vec::new(),
            Err(m) => std::iter::once(1).chain(text_words(m)).collect(),
        };
        let all = self.all_gather_u64(&bytes)?;
        for (rank, b) in all.iter().enumerate() {
            if !b.is_empty() {
                return Err(CommError::Remote {
                    rank,
                    message: words_text(&b[1..]),
                });
            }
        }
        Ok(())
    }
}

/// A message as words for the `u64` collectives, one byte a word ([`words_text`] reads it).
pub(crate) fn text_words(text: &str) -> impl Iterator<Item = u64> + '_ {
    text.bytes().map(u64::from)
}

/// The message of [`text_words`] back.
pub(crate) fn words_text(words: &[u64]) -> String {
    String::from_utf8_lossy(&words.iter().map(|&c| c as u8).collect::<Vec<u8>>()).into_owned()
}

/// `local` where every rank succeeded (collective); otherwise an error on every rank: its own
/// where this rank failed, else the lowest failing rank's message ([`CommError::Remote`])
/// wrapped by `wrap`, so that no rank goes on to a collective the others never reach. One
/// rank returns `local` as it is.
pub fn agreed<T, E: std::fmt::Display>(
    comm: &dyn Communicator,
    local: Result<T, E>,
    wrap: impl FnOnce(CommError) -> E,
) -> Result<T, E> {
    if comm.size() == 1 {
        return local;
    }
    let outcome = local.as_ref().map(|_| ()).map_err(|e| e.to_string());
    match (comm.agree(outcome), local) {
        (Ok(()), local) => local,
        (Err(_), Err(own)) => Err(own),
        (Err(e), Ok(_)) => Err(wrap(e)),
    }
}

/// One value over the ranks: its smallest, mean and largest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    /// Smallest value over the ranks.
    pub min: f64,
    /// Mean over the ranks.
    pub mean: f64,
    /// Largest value over the ranks.
    pub max: f64,
}

/// The [`Spread`] over the ranks of each of `local`'s values (collective; every rank passes
/// as many values, in the same order): how a per-rank clock or counter varies between ranks.
///
/// ```
/// use mobo::comm::{spread, SerialComm};
/// let s = spread(&SerialComm, &[2.0, 5.0]).unwrap();
/// assert_eq!((s[1].min, s[1].mean, s[1].max), (5.0, 5.0, 5.0));
/// ```
pub fn spread(comm: &dyn Communicator, local: &[f64]) -> Result<Vec<Spread>, CommError> {
    let all = comm.all_gather_f64(local)?;
    if let Some(r) = all.iter().find(|r| r.len() != local.len()) {
        return Err(CommError::Ranks {
            what: "per-rank values to spread",
            got: r.len(),
            ranks: all.len(),
        });
    }
    let k = all.len() as f64;
    Ok((0..local.len())
        .map(|j| {
            let col = || all.iter().map(|r| r[j]);
            Spread {
                min: col().fold(f64::INFINITY, f64::min),
                mean: col().sum::<f64>() / k,
                max: col().fold(f64::NEG_INFINITY, f64::max),
            }
        })
        .collect())
}

/// The block of rows `[r·n/K, (r+1)·n/K)` of `n` that rank `r` of `K` takes (contiguous,
/// sizes differing by at most one, in rank order).
///
/// ```
/// assert_eq!(mobo::comm::block_rows(10, 2, 3), 6..10);
/// ```
pub fn block_rows(n: usize, rank: usize, ranks: usize) -> std::ops::Range<usize> {
    rank * n / ranks..(rank + 1) * n / ranks
}

/// The element-wise sum over the ranks of `local` (every rank passes as many values), the same
/// bits on every rank (collective): rank `r` sums block `r` ([`block_rows`]) of every rank's
/// vector in rank order, and the summed blocks are all-gathered. A rank sends and receives
/// about `2n (K − 1)/K` values, where an all-gather of the vectors would bring it `n (K − 1)`.
/// One rank returns `local` as it is.
///
/// ```
/// use mobo::comm::{sum_in_rank_order, SerialComm};
/// assert_eq!(sum_in_rank_order(&SerialComm, &[1.5, -2.0]).unwrap(), vec![1.5, -2.0]);
/// ```
pub fn sum_in_rank_order(comm: &dyn Communicator, local: &[f64]) -> Result<Vec<f64>, CommError> {
    let k = comm.size();
    if k == 1 {
        return Ok(local.to_vec());
    }
    let n = local.len();
    let send: Vec<Vec<f64>> = (0..k)
        .map(|r| local[block_rows(n, r, k)].to_vec())
        .collect();
    let parts = comm.all_to_all_f64(&send)?;
    let mine = block_rows(n, comm.rank(), k);
    if let Some(p) = parts.iter().find(|p| p.len() != mine.len()) {
        return Err(CommError::Disagree(format!(
            "a block of a sum over the ranks has {} values, this rank's {}",
            p.len(),
            mine.len()
        )));
    }
    let mut block = parts[0].clone();
    for p in &parts[1..] {
        for (s, v) in block.iter_mut().zip(p) {
            *s += v;
        }
    }
    let blocks = comm.all_gather_f64(&block)?;
    let total: Vec<f64> = blocks.concat();
    if total.len() != n {
        return Err(CommError::Disagree(format!(
            "a sum over the ranks has {} values, this rank's vector {n}",
            total.len()
        )));
    }
    Ok(total)
}

/// One rank, no MPI: collectives are identities and copies.
#[derive(Clone, Copy, Debug, Default)]
pub struct SerialComm;

fn one<T: Clone>(what: &'static str, send: &[Vec<T>]) -> Result<Vec<Vec<T>>, CommError> {
    if send.len() != 1 {
        return Err(CommError::Ranks {
            what,
            got: send.len(),
            ranks: 1,
        });
    }
    Ok(send.to_vec())
}

impl Communicator for SerialComm {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn all_min(&self, _v: &mut [f64]) -> Result<(), CommError> {
        Ok(())
    }
    fn all_max(&self, _v: &mut [f64]) -> Result<(), CommError> {
        Ok(())
    }
    fn all_sum_u64(&self, _v: &mut [u64]) -> Result<(), CommError> {
        Ok(())
    }
    fn all_gather_u64(&self, local: &[u64]) -> Result<Vec<Vec<u64>>, CommError> {
        Ok(vec![local.to_vec()])
    }
    fn all_gather_f64(&self, local: &[f64]) -> Result<Vec<Vec<f64>>, CommError> {
        Ok(vec![local.to_vec()])
    }
    fn gather_f64(&self, local: &[f64], root: usize) -> Result<Vec<Vec<f64>>, CommError> {
        if root != 0 {
            return Err(CommError::NoSuchRank {
                rank: root,
                ranks: 1,
            });
        }
        Ok(vec![local.to_vec()])
    }
    fn all_to_all_u64(&self, send: &[Vec<u64>]) -> Result<Vec<Vec<u64>>, CommError> {
        one("all-to-all buffer list", send)
    }
    fn all_to_all_f64(&self, send: &[Vec<f64>]) -> Result<Vec<Vec<f64>>, CommError> {
        one("all-to-all buffer list", send)
    }
    fn exchange_f64(
        &self,
        sends: &[(usize, &[f64])],
        recvs: &[(usize, usize)],
    ) -> Result<Vec<Vec<f64>>, CommError> {
        // Only messages to oneself are possible; they are delivered in order.
        let mut out = Vec::with_capacity(recvs.len());
        let mut mine = sends.iter().filter(|s| s.0 == 0);
        for &(r, n) in recvs {
            if r != 0 {
                return Err(CommError::NoSuchRank { rank: r, ranks: 1 });
            }
            let b = mine.next().map(|s| s.1.to_vec()).unwrap_or_default();
            if b.len() != n {
                return Err(CommError::Ranks {
                    what: "self message",
                    got: b.len(),
                    ranks: 1,
                });
            }
            out.push(b);
        }
        if let Some(&(r, _)) = sends.iter().find(|s| s.0 != 0) {
            return Err(CommError::NoSuchRank { rank: r, ranks: 1 });
        }
        Ok(out)
    }
    fn bytes_sent(&self) -> u64 {
        0
    }
}
