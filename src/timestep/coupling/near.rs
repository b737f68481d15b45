//! The near-singular corrections (and contact pushes) that each source cell exerts at this
//! rank's points in its near zone.

use super::*;

impl Coupling {
    /// For each source cell (in the given order), the corrections at this rank's points in its
    /// near zone, and the contact pushes it exerts on them.
    pub(super) fn near_corrections(
        &self,
        ids: &[usize],
        sources: &[SourceCell<'_>],
    ) -> Result<NearResult, TimestepError> {
        let (p, mu) = (self.p, self.params.viscosity);
        // Cell list of this rank's cells by centroid, bins as wide as the largest reach.
        let reach_max = sources
            .iter()
            .map(|s| s.quad.radius + s.quad.delta)
            .fold(0.0, f64::max);
        let radius_max = self.cells.iter().map(|c| c.radius).fold(0.0, f64::max);
        let h = (reach_max + radius_max).max(f64::MIN_POSITIVE);
        let bin = |x: [f64; 3]| x.map(|v| (v / h).floor() as i64);
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (i, c) in self.cells.iter().enumerate() {
            grid.entry(bin(c.centroid)).or_default().push(i);
        }
        let repulsion: Mutex<Vec<Push>> = Mutex::new(Vec::new());
        let corrections = sources
            .par_iter()
            .map(|s| -> Result<_, TimestepError> {
                let cj = s.quad;
                let reach = cj.radius + cj.delta;
                let b = bin(cj.centroid);
                let mut near_cells: Vec<usize> = Vec::new();
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            if let Some(list) = grid.get(&[b[0] + dx, b[1] + dy, b[2] + dz]) {
                                near_cells.extend(list.iter().copied().filter(|&i| {
                                    let ci = &self.cells[i];
                                    ids[i] != s.id
                                        && dist(ci.centroid, cj.centroid) <= ci.radius + reach
                                }));
                            }
                        }
                    }
                }
                near_cells.sort_unstable();
                let mut cand: Vec<(usize, usize)> = Vec::new();
                for &i in &near_cells {
                    for (k, &x) in self.cells[i].targets.iter().enumerate() {
                        if dist(x, cj.centroid) <= reach {
                            cand.push((i, k));
                        }
                    }
                }
                if cand.is_empty() {
                    return Ok(Vec::new());
                }
                let mut guard = self.engine();
                let e = &mut *guard;
                e.near.set_surface(s.coefs).map_err(vesicle)?;
                let mut near: Vec<(usize, usize, f64)> = Vec::new();
                let mut near_infos = Vec::new();
                let mut push: Vec<Push> = Vec::new();
                let (range, strength) = (
                    (self.params.repulsion_range * cj.r_eq).min(cj.delta),
                    self.params.repulsion_strength,
                );
                for &(i, k) in &cand {
                    let x = self.cells[i].targets[k];
                    let info = e.near.classify(x).map_err(vesicle)?;
                    let signed = if info.inside {
                        -info.distance
                    } else {
                        info.distance
                    };
                    if info.distance < cj.delta || info.inside {
                        near.push((i, k, signed));
                        near_infos.push(info);
                    }
                    if strength > 0.0 && signed < range {
                        // Along the outward normal of cell j at its nearest quadrature point.
                        let (kn, _) = cj.sources.iter().enumerate().fold(
                            (0, f64::INFINITY),
                            |(kb, db), (kk, y)| {
                                let d = dist2(x, *y);
                                if d < db {
                                    (kk, d)
                                } else {
                                    (kb, db)
                                }
                            },
                        );
                        let mag = if signed >= 0.0 {
                            strength * (1.0 - signed / range).powi(2)
                        } else {
                            strength * (1.0 - signed / range)
                        };
                        push.push((i, k, s.id, cj.normals[kn].map(|v| v * mag)));
                    }
                }
                if !push.is_empty() {
                    let mut rep = repulsion.lock().expect("repulsion lock");
                    rep.extend(push);
                }
                if near.is_empty() {
                    return Ok(Vec::new());
                }
                let pts: Vec<[f64; 3]> = near
                    .iter()
                    .map(|&(i, k, _)| self.cells[i].targets[k])
                    .collect();
                let mut u_near = vec![0.0; 3 * pts.len()];
                e.near
                    .evaluate_classified(
                        LayerKernel::SingleLayer { viscosity: mu },
                        s.traction,
                        None,
                        &pts,
                        &near_infos,
                        &mut u_near,
                    )
                    .map_err(vesicle)?;
                let mut smooth = vec![0.0; 3 * pts.len()];
                e.block.set_points(&cj.sources, &cj.density, 3);
                Stokeslet.eval_block(&pts, &e.block.all(), &mut smooth);
                let m = pts.len();
                if let Some(dl) = s.dl {
                    // The double layer of cell j: near-singular value minus the smooth sum the
                    // FMM counted, at the same points.
                    let mut d_near = vec![0.0; 3 * m];
                    let near_dl = match &mut e.near_dl {
                        Some(o) => o,
                        None => e
                            .near_dl
                            .insert(OffSurface::new(p, DOUBLE_LAYER_NEAR).map_err(vesicle)?),
                    };
                    near_dl.set_surface(s.coefs).map_err(vesicle)?;
                    near_dl
                        .evaluate(LayerKernel::DoubleLayer, dl, &pts, &mut d_near)
                        .map_err(vesicle)?;
                    let mut d_smooth = vec![0.0; 3 * m];
                    set_oriented(&mut e.dl_block, &cj.sources, &cj.normals, &cj.dl_density);
                    Stresslet.eval_block(&pts, &e.dl_block.all(), &mut d_smooth);
                    for t in 0..m {
                        for c in 0..3 {
                            u_near[c * m + t] += d_near[c * m + t];
                            smooth[3 * t + c] += d_smooth[3 * t + c];
                        }
                    }
                }
                Ok(near
                    .iter()
                    .enumerate()
                    .map(|(t, &(i, k, d))| {
                        let du = std::array::from_fn(|c| u_near[c * m + t] - smooth[3 * t + c]);
                        (i, k, du, d)
                    })
                    .collect())
            })
            .collect::<Result<Vec<Vec<NearCorrection>>, _>>();
        Ok(NearResult {
            corrections: corrections?,
            pushes: repulsion.into_inner().expect("repulsion lock"),
        })
    }
}
