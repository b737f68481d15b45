//! How points reach the ranks that own their keys, and how per-point values travel between the
//! callers' order and the owners' sorted order.

use super::*;

/// How per-point values travel between the caller's ranks and order and the owners' sorted
/// order (densities forward, results back).
#[derive(Clone, Debug, Default)]
pub struct Route {
    /// For each rank, the caller's point indices sent there, in order.
    outgoing: Vec<Vec<usize>>,
    /// Number of points received from each rank.
    incoming: Vec<usize>,
    /// Sorted point `i` is entry `from[i]` of the received points (concatenated by rank).
    from: Vec<usize>,
}

impl Route {
    /// Values of the caller's points (`dim` per point, caller order) to this rank's sorted
    /// points.
    pub fn forward(
        &self,
        comm: &dyn Communicator,
        data: &[f64],
        dim: usize,
    ) -> Result<Vec<f64>, CommError> {
        let send: Vec<Vec<f64>> = self
            .outgoing
            .iter()
            .map(|idx| {
                idx.iter()
                    .flat_map(|&i| data[i * dim..(i + 1) * dim].iter().copied())
                    .collect()
            })
            .collect();
        let recv: Vec<f64> = comm.all_to_all_f64(&send)?.concat();
        let mut out = vec![0.0; self.from.len() * dim];
        for (o, &f) in out.chunks_exact_mut(dim).zip(&self.from) {
            o.copy_from_slice(&recv[f * dim..(f + 1) * dim]);
        }
        Ok(out)
    }

    /// Values of this rank's sorted points back to the caller's points (`out`, caller order).
    pub fn backward(
        &self,
        comm: &dyn Communicator,
        sorted: &[f64],
        dim: usize,
        out: &mut [f64],
    ) -> Result<(), CommError> {
        let mut flat = vec![0.0; sorted.len()];
        for (v, &f) in sorted.chunks_exact(dim).zip(&self.from) {
            flat[f * dim..(f + 1) * dim].copy_from_slice(v);
        }
        let mut at = 0;
        let send: Vec<Vec<f64>> = self
            .incoming
            .iter()
            .map(|&n| {
                let v = flat[at * dim..(at + n) * dim].to_vec();
                at += n;
                v
            })
            .collect();
        let recv = comm.all_to_all_f64(&send)?;
        for (idx, vals) in self.outgoing.iter().zip(&recv) {
            for (&i, v) in idx.iter().zip(vals.chunks_exact(dim)) {
                out[i * dim..(i + 1) * dim].copy_from_slice(v);
            }
        }
        Ok(())
    }

    /// Number of the caller's points.
    pub fn n_caller(&self) -> usize {
        self.outgoing.iter().map(Vec::len).sum()
    }

    /// Number of the caller's points that another rank owns (`rank`: the caller's): the
    /// points whose positions, densities and results cross between ranks.
    pub fn n_moved(&self, rank: usize) -> usize {
        self.outgoing
            .iter()
            .enumerate()
            .filter(|&(r, _)| r != rank)
            .map(|(_, v)| v.len())
            .sum()
    }
}

/// Points as one rank receives them: sorted by (key, global index).
pub(super) struct Sorted {
    pub(super) points: Vec<[f64; 3]>,
    pub(super) normals: Option<Vec<[f64; 3]>>,
    pub(super) keys: Vec<u64>,
    pub(super) route: Route,
}

/// Send points to the owners of their keys and sort them by (key, global index).
pub(super) fn distribute(
    comm: &dyn Communicator,
    domain: &Domain,
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    splitters: &[u64],
) -> Result<Sorted, CommError> {
    let k = comm.size();
    let counts = comm.all_gather_u64(&[points.len() as u64])?;
    let offset: u64 = counts[..comm.rank()].iter().map(|c| c[0]).sum();
    let width = if normals.is_some() { 8 } else { 5 };
    let mut outgoing = vec![Vec::new(); k];
    let mut send = vec![Vec::new(); k];
    for (i, p) in points.iter().enumerate() {
        let key = domain.key(*p);
        let r = splitters.partition_point(|&s| s <= key) - 1;
        outgoing[r].push(i);
        let buf = &mut send[r];
        buf.push(key);
        buf.push(offset + i as u64);
        buf.extend(bits(*p));
        if let Some(n) = normals {
            buf.extend(bits(n[i]));
        }
    }
    let recv = comm.all_to_all_u64(&send)?;
    let incoming: Vec<usize> = recv.iter().map(|b| b.len() / width).collect();
    let flat: Vec<u64> = recv.concat();
    let n = flat.len() / width;
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_unstable_by_key(|&i| (flat[i * width], flat[i * width + 1]));
    let rec = |i: usize| &flat[i * width..(i + 1) * width];
    Ok(Sorted {
        points: order.iter().map(|&i| unbits(&rec(i)[2..5])).collect(),
        normals: normals
            .is_some()
            .then(|| order.iter().map(|&i| unbits(&rec(i)[5..8])).collect()),
        keys: order.iter().map(|&i| rec(i)[0]).collect(),
        route: Route {
            outgoing,
            incoming,
            from: order,
        },
    })
}
