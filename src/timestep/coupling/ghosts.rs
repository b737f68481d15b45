//! Ghost cells: copies of the other ranks' cells whose near zones reach this rank's cells,
//! exchanged for the near-singular corrections.

use super::*;

/// A cell of another rank, copied here for the near-singular corrections at this rank's points.
pub(super) struct Ghost {
    pub(super) id: usize,
    pub(super) coefs: Vec<f64>,
    pub(super) traction: Vec<f64>,
    pub(super) dl: Option<Vec<f64>>,
    pub(super) quad: CellQuadrature,
}

impl Coupling {
    /// Send each own cell to the other ranks whose cells' bounding box its near zone reaches;
    /// receive theirs (collective). Each ghost's quadrature is recomputed here from its
    /// coefficients and densities, as its owner computed it.
    pub(super) fn exchange_ghosts(
        &mut self,
        comm: &dyn Communicator,
        ids: &[usize],
        coefs: &[&[f64]],
        tractions: &[&[f64]],
        double_layer: &[Option<&[f64]>],
    ) -> Result<Vec<Ghost>, TimestepError> {
        let k = comm.size();
        if k == 1 {
            return Ok(Vec::new());
        }
        let me = comm.rank();
        // This rank's targets' box (empty: +∞ … −∞).
        let mut bbox = [f64::INFINITY, f64::INFINITY, f64::INFINITY, 0.0, 0.0, 0.0];
        bbox[3..].fill(f64::NEG_INFINITY);
        for c in &self.cells {
            for d in 0..3 {
                bbox[d] = bbox[d].min(c.centroid[d] - c.radius);
                bbox[3 + d] = bbox[3 + d].max(c.centroid[d] + c.radius);
            }
        }
        let boxes = comm.all_gather_f64(&bbox).map_err(TimestepError::Comm)?;
        let (ncoef, n3) = (3 * ((self.p + 1) * (self.p + 1) - 1), 3 * self.n_grid());
        let record = 2 + ncoef + 2 * n3;
        let mut send: Vec<Vec<f64>> = vec![Vec::new(); k];
        for (j, c) in self.cells.iter().enumerate() {
            let reach = c.radius + c.delta;
            for (r, b) in boxes.iter().enumerate() {
                if r == me || b.len() != 6 {
                    continue;
                }
                // Distance from the centroid to the box.
                let d2: f64 = (0..3)
                    .map(|d| {
                        (b[d] - c.centroid[d])
                            .max(c.centroid[d] - b[3 + d])
                            .max(0.0)
                    })
                    .map(|g| g * g)
                    .sum();
                if b[0] <= b[3] && d2 <= reach * reach {
                    let buf = &mut send[r];
                    buf.push(ids[j] as f64);
                    let dl = double_layer.get(j).copied().flatten();
                    buf.push(if dl.is_some() { 1.0 } else { 0.0 });
                    buf.extend_from_slice(coefs[j]);
                    buf.extend_from_slice(tractions[j]);
                    match dl {
                        Some(d) => buf.extend_from_slice(d),
                        None => buf.extend(std::iter::repeat_n(0.0, n3)),
                    }
                }
            }
        }
        self.stats.ghost_bytes += send.iter().map(|b| 8 * b.len() as u64).sum::<u64>();
        let received = comm.all_to_all_f64(&send).map_err(TimestepError::Comm)?;
        let mut raw = Vec::new();
        for (r, buf) in received.iter().enumerate() {
            if buf.len() % record != 0 {
                return Err(TimestepError::Comm(CommError::Ranks {
                    what: "ghost cell records received",
                    got: buf.len(),
                    ranks: r,
                }));
            }
            for rec in buf.chunks_exact(record) {
                let coefs = rec[2..2 + ncoef].to_vec();
                let traction = rec[2 + ncoef..2 + ncoef + n3].to_vec();
                let dl = (rec[1] != 0.0).then(|| rec[2 + ncoef + n3..].to_vec());
                raw.push((rec[0] as usize, coefs, traction, dl));
            }
        }
        self.stats.ghost_cells += raw.len();
        let this = &*self;
        raw.into_par_iter()
            .map(|(id, coefs, traction, dl)| {
                let quad = this.quadrature(&coefs, &traction, dl.as_deref())?;
                Ok(Ghost {
                    id,
                    coefs,
                    traction,
                    dl,
                    quad,
                })
            })
            .collect()
    }
}
