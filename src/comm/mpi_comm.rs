//! [`Communicator`] over `MPI_COMM_WORLD` (rsmpi, the system's MPI).

use std::cell::Cell;

use mpi::collective::SystemOperation;
use mpi::datatype::{Partition, PartitionMut};
use mpi::environment::Threading;
use mpi::topology::Communicator as _;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::Count;

use super::{CommError, Communicator};

/// The world communicator of an initialised MPI environment. Create one per process with
/// [`MpiComm::init`]; MPI is finalised when it is dropped.
pub struct MpiComm {
    world: SimpleCommunicator,
    sent: Cell<u64>,
    messages: Cell<u64>,
    _universe: mpi::environment::Universe,
}

impl MpiComm {
    /// Initialise MPI (once per process) for ranks × threads: the thread that calls this is
    /// the only one that should call MPI, while rayon's threads compute (`MPI_THREAD_FUNNELED`;
    /// an `MpiComm` is not `Sync`, so it cannot be shared with rayon's workers, and the run
    /// loops keep it on the thread that made it). `None` if MPI was already initialised.
    pub fn init() -> Option<Self> {
        let (universe, provided) = mpi::initialize_with_threading(Threading::Funneled)?;
        if provided < Threading::Funneled && rayon::current_num_threads() > 1 {
            eprintln!(
                "warning: this MPI library provides {provided:?} threading, not Funneled; \
                 run one thread per rank (RAYON_NUM_THREADS=1)"
            );
        }
        let world = universe.world();
        Some(MpiComm {
            world,
            sent: Cell::new(0),
            messages: Cell::new(0),
            _universe: universe,
        })
    }

    /// End every rank at once with `code` (for errors found on one rank only, after which the
    /// collectives could not be matched).
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }

    fn count(n: usize) -> Result<Count, CommError> {
        Count::try_from(n).map_err(|_| CommError::TooLong(n))
    }

    /// Count `values` of `width` bytes sent in `messages` messages.
    fn counted(&self, values: usize, width: usize, messages: usize) {
        self.sent.set(self.sent.get() + (values * width) as u64);
        self.messages.set(self.messages.get() + messages as u64);
    }

    fn gather<T: Equivalence + Default + Clone>(
        &self,
        local: &[T],
    ) -> Result<Vec<Vec<T>>, CommError> {
        let k = self.size();
        let n = Self::count(local.len())?;
        let mut counts = vec![0 as Count; k];
        self.world.all_gather_into(&n, &mut counts[..]);
        let displs = displacements(&counts)?;
        let total: usize = counts.iter().map(|&c| c as usize).sum();
        let mut buf = vec![T::default(); total];
        {
            let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
            self.world.all_gather_varcount_into(local, &mut part);
        }
        // The counts and the values, each to every other rank.
        self.counted(local.len() * (k - 1), std::mem::size_of::<T>(), 2 * (k - 1));
        Ok(split(&buf, &counts))
    }

    fn to_all<T: Equivalence + Default + Clone>(
        &self,
        send: &[Vec<T>],
    ) -> Result<Vec<Vec<T>>, CommError> {
        let k = self.size();
        if send.len() != k {
            return Err(CommError::Ranks {
                what: "all-to-all buffer list",
                got: send.len(),
                ranks: k,
            });
        }
        let scounts = send
            .iter()
            .map(|b| Self::count(b.len()))
            .collect::<Result<Vec<_>, _>>()?;
        let mut rcounts = vec![0 as Count; k];
        self.world.all_to_all_into(&scounts[..], &mut rcounts[..]);
        let sdispls = displacements(&scounts)?;
        let rdispls = displacements(&rcounts)?;
        let flat: Vec<T> = send.iter().flatten().cloned().collect();
        let total: usize = rcounts.iter().map(|&c| c as usize).sum();
        let mut buf = vec![T::default(); total];
        {
            let sp = Partition::new(&flat[..], &scounts[..], &sdispls[..]);
            let mut rp = PartitionMut::new(&mut buf[..], &rcounts[..], &rdispls[..]);
            self.world.all_to_all_varcount_into(&sp, &mut rp);
        }
        let me = self.rank();
        let off_rank: usize = send
            .iter()
            .enumerate()
            .filter(|(r, _)| *r != me)
            .map(|(_, b)| b.len())
            .sum();
        // The counts to every other rank, the values to those that get some.
        let partners = send
            .iter()
            .enumerate()
            .filter(|(r, b)| *r != me && !b.is_empty())
            .count();
        self.counted(off_rank + k, std::mem::size_of::<T>(), k - 1 + partners);
        Ok(split(&buf, &rcounts))
    }
}

fn displacements(counts: &[Count]) -> Result<Vec<Count>, CommError> {
    let mut at = 0usize;
    let mut d = Vec::with_capacity(counts.len());
    for &c in counts {
        d.push(MpiComm::count(at)?);
        at += c as usize;
    }
    Ok(d)
}

fn split<T: Clone>(buf: &[T], counts: &[Count]) -> Vec<Vec<T>> {
    let mut at = 0;
    counts
        .iter()
        .map(|&c| {
            let v = buf[at..at + c as usize].to_vec();
            at += c as usize;
            v
        })
        .collect()
}

impl Communicator for MpiComm {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn all_min(&self, v: &mut [f64]) -> Result<(), CommError> {
        let local = v.to_vec();
        self.world
            .all_reduce_into(&local[..], v, SystemOperation::min());
        Ok(())
    }
    fn all_max(&self, v: &mut [f64]) -> Result<(), CommError> {
        let local = v.to_vec();
        self.world
            .all_reduce_into(&local[..], v, SystemOperation::max());
        Ok(())
    }
    fn all_sum_u64(&self, v: &mut [u64]) -> Result<(), CommError> {
        let local = v.to_vec();
        self.world
            .all_reduce_into(&local[..], v, SystemOperation::sum());
        Ok(())
    }
    fn all_gather_u64(&self, local: &[u64]) -> Result<Vec<Vec<u64>>, CommError> {
        self.gather(local)
    }
    fn all_gather_f64(&self, local: &[f64]) -> Result<Vec<Vec<f64>>, CommError> {
        self.gather(local)
    }
    fn gather_f64(&self, local: &[f64], root: usize) -> Result<Vec<Vec<f64>>, CommError> {
        let k = self.size();
        if root >= k {
            return Err(CommError::NoSuchRank {
                rank: root,
                ranks: k,
            });
        }
        let n = Self::count(local.len())?;
        let proc = self.world.process_at_rank(root as i32);
        if self.rank() != root {
            proc.gather_into(&n);
            proc.gather_varcount_into(local);
            self.counted(local.len() + 1, 8, 2);
            return Ok(Vec::new());
        }
        let mut counts = vec![0 as Count; k];
        proc.gather_into_root(&n, &mut counts[..]);
        let displs = displacements(&counts)?;
        let total: usize = counts.iter().map(|&c| c as usize).sum();
        let mut buf = vec![0.0; total];
        {
            let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
            proc.gather_varcount_into_root(local, &mut part);
        }
        Ok(split(&buf, &counts))
    }
    fn all_to_all_u64(&self, send: &[Vec<u64>]) -> Result<Vec<Vec<u64>>, CommError> {
        self.to_all(send)
    }
    fn all_to_all_f64(&self, send: &[Vec<f64>]) -> Result<Vec<Vec<f64>>, CommError> {
        self.to_all(send)
    }
    fn exchange_f64(
        &self,
        sends: &[(usize, &[f64])],
        recvs: &[(usize, usize)],
    ) -> Result<Vec<Vec<f64>>, CommError> {
        let k = self.size();
        if let Some(&(r, _)) = sends.iter().find(|(r, _)| *r >= k) {
            return Err(CommError::NoSuchRank { rank: r, ranks: k });
        }
        for &(r, n) in recvs {
            if r >= k {
                return Err(CommError::NoSuchRank { rank: r, ranks: k });
            }
            Self::count(n)?;
        }
        let mut out: Vec<Vec<f64>> = recvs.iter().map(|&(_, n)| vec![0.0; n]).collect();
        mpi::request::multiple_scope(sends.len() + recvs.len(), |scope, coll| {
            for (buf, &(r, _)) in out.iter_mut().zip(recvs) {
                let req = self
                    .world
                    .process_at_rank(r as i32)
                    .immediate_receive_into(scope, &mut buf[..]);
                coll.add(req);
            }
            for &(r, b) in sends {
                let req = self
                    .world
                    .process_at_rank(r as i32)
                    .immediate_send(scope, b);
                coll.add(req);
            }
            let mut done = Vec::new();
            coll.wait_all(&mut done);
        });
        let me = self.rank();
        let bytes: usize = sends
            .iter()
            .filter(|(r, _)| *r != me)
            .map(|(_, b)| b.len())
            .sum();
        let partners = sends.iter().filter(|(r, _)| *r != me).count();
        self.counted(bytes, 8, partners);
        Ok(out)
    }
    fn bytes_sent(&self) -> u64 {
        self.sent.get()
    }
    fn messages_sent(&self) -> u64 {
        self.messages.get()
    }
}
