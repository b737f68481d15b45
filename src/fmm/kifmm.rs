//! Kernel-independent FMM (Ying, Biros & Zorin, J. Comput. Phys. 196, 2004): reference version.
//!
//! Every box `B` of half-width `h` carries, on cube surfaces of `n = 6(p−1)² + 2` points (`p`
//! points per edge) around its centre:
//!
//! * an upward equivalent density on the surface of radius `1.05h`, fitted so that its field on
//!   the upward check surface (radius `2.95h`) equals that of the sources inside `B` (P2M for
//!   leaves, M2M from the children's equivalent densities otherwise);
//! * a downward equivalent density on the surface of radius `2.5h` (strictly inside the nearest
//!   far sources at `2.95h`), fitted so that its field on
//!   the downward check surface (radius `1.05h`) equals that of the far sources: the parent's
//!   downward density (L2L), the upward densities of the V list (M2L) and the sources of the X
//!   list (P2L).
//!
//! Targets in a leaf get the leaf's downward density (L2P), the sources of the U list (P2P) and
//! the upward densities of the W list (M2P). The fits solve `K c = u` with a truncated-SVD
//! pseudo-inverse of the equivalent-to-check kernel matrix, one per level. Sources act through
//! the source kernel (`KS`, which may be a double layer with orientations); equivalent densities
//! act through a single-layer equivalent kernel (`KE`) with the same output (Laplace for Laplace,
//! Stokeslet for Stokes kernels).
//!
//! This version evaluates every translation by direct kernel evaluation between surfaces (dense
//! M2L, `O(n²)` per V-list pair): it is the correctness reference for the accelerated
//! translations (FFT or SVD-compressed M2L) that come next.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};
use rayon::prelude::*;

use super::kernels::Kernel;
use super::octree::{Lists, Octree};
use super::operators::kernel_matrix;
use super::FmmError;

pub use super::operators::{DOWN_EQUIV, INNER, UP_CHECK};

/// Relative cut-off of the truncated-SVD pseudo-inverses (1e-10 measured best for this
/// explicit-inverse version: 1e-12 and 1e-14 amplify round-off so that errors grow with the
/// order beyond p = 8; the fast FMM keeps the inverse factored instead).
pub const RCOND: f64 = 1e-10;

/// Points of the surface of the cube `[-1, 1]³` with `p ≥ 2` points per edge.
pub fn cube_surface(p: usize) -> Vec<[f64; 3]> {
    super::surface::CubeSurface::new(p).points
}

/// Truncated-SVD pseudo-inverse (singular values below `rcond · σ_max` dropped).
fn pinv(a: &Mat<f64>, rcond: f64) -> Result<Mat<f64>, FmmError> {
    let svd = a
        .svd()
        .map_err(|_| FmmError::Svd("check-to-equivalent matrix"))?;
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    let smax = s.iter().fold(0.0f64, |m, &x| m.max(x));
    let k = s.nrows();
    let mut vs = Mat::<f64>::zeros(v.nrows(), k);
    for j in 0..k {
        let inv = if s[j] > rcond * smax { 1.0 / s[j] } else { 0.0 };
        for i in 0..v.nrows() {
            vs[(i, j)] = v[(i, j)] * inv;
        }
    }
    let mut out = Mat::<f64>::zeros(v.nrows(), u.nrows());
    matmul(
        out.as_mut(),
        Accum::Replace,
        vs.as_ref(),
        u.get(.., ..k).transpose(),
        1.0,
        Par::Seq,
    );
    Ok(out)
}

/// The FMM over one set of sources and targets, reusable for many densities.
pub struct Kifmm<'k, KS: Kernel, KE: Kernel> {
    ks: &'k KS,
    ke: &'k KE,
    /// The tree.
    pub tree: Octree,
    /// Its interaction lists.
    pub lists: Lists,
    surf: Vec<[f64; 3]>,
    /// Per level: pseudo-inverses of the upward and downward equivalent-to-check matrices.
    up: Vec<Mat<f64>>,
    down: Vec<Mat<f64>>,
    normals_sorted: Option<Vec<[f64; 3]>>,
    /// Points per edge of the surfaces.
    pub order: usize,
}

impl<'k, KS: Kernel, KE: Kernel> Kifmm<'k, KS, KE> {
    /// Build the tree, the lists and the per-level operators.
    pub fn new(
        ks: &'k KS,
        ke: &'k KE,
        sources: &[[f64; 3]],
        normals: Option<&[[f64; 3]]>,
        targets: &[[f64; 3]],
        order: usize,
        leaf_size: usize,
    ) -> Result<Self, FmmError> {
        if order < 2 {
            return Err(FmmError::Shape(format!(
                "FMM order must be at least 2, got {order}"
            )));
        }
        if ks.output_dim() != ke.output_dim() {
            return Err(FmmError::Shape(
                "source and equivalent kernels differ in output".into(),
            ));
        }
        if ks.needs_normals() && normals.map(|n| n.len()) != Some(sources.len()) {
            return Err(FmmError::Shape(format!(
                "{} needs one normal per source",
                ks.name()
            )));
        }
        let tree = Octree::new(sources, targets, leaf_size);
        let lists = tree.lists();
        let surf = cube_surface(order);
        let mut up = Vec::new();
        let mut down = Vec::new();
        for level in 0..tree.depth() {
            let h = tree.nodes[0].half / f64::powi(2.0, level as i32);
            // Equivalent → check kernel matrices for a box centred at the origin.
            let matrix = |eq_r: f64, ck_r: f64| {
                let at = |rho: f64| -> Vec<[f64; 3]> {
                    surf.iter().map(|c| c.map(|v| v * rho * h)).collect()
                };
                kernel_matrix(ke, &at(ck_r), &at(eq_r))
            };
            up.push(pinv(&matrix(INNER, UP_CHECK), RCOND)?);
            down.push(pinv(&matrix(DOWN_EQUIV, INNER), RCOND)?);
        }
        let normals_sorted = normals.map(|nm| tree.source_perm.iter().map(|&i| nm[i]).collect());
        Ok(Kifmm {
            ks,
            ke,
            tree,
            lists,
            surf,
            up,
            down,
            normals_sorted,
            order,
        })
    }

    fn surface(&self, b: usize, radius: f64) -> impl Iterator<Item = [f64; 3]> + '_ {
        let nd = &self.tree.nodes[b];
        let s = radius * nd.half;
        self.surf.iter().map(move |p| {
            [
                nd.center[0] + s * p[0],
                nd.center[1] + s * p[1],
                nd.center[2] + s * p[2],
            ]
        })
    }

    /// Add the field of box `src`'s equivalent density (on the surface of radius `radius`) at
    /// the points `at` to `out` (`output_dim` values per point).
    fn equiv_to_points(
        &self,
        src: usize,
        radius: f64,
        density: &[f64],
        at: &[[f64; 3]],
        out: &mut [f64],
    ) {
        let (dt, de) = (self.ke.output_dim(), self.ke.density_dim());
        for (y, q) in self.surface(src, radius).zip(density.chunks_exact(de)) {
            for (x, o) in at.iter().zip(out.chunks_exact_mut(dt)) {
                self.ke
                    .accumulate([x[0] - y[0], x[1] - y[1], x[2] - y[2]], q, [0.0; 3], o);
            }
        }
    }

    /// Add the field of box `src`'s own sources at the points `at`.
    fn sources_to_points(&self, src: usize, density: &[f64], at: &[[f64; 3]], out: &mut [f64]) {
        let (dt, ds) = (self.ks.output_dim(), self.ks.density_dim());
        for j in self.tree.nodes[src].sources.clone() {
            let y = self.tree.sources_sorted[j];
            let q = &density[j * ds..(j + 1) * ds];
            let nrm = self.normals_sorted.as_ref().map_or([0.0; 3], |n| n[j]);
            for (x, o) in at.iter().zip(out.chunks_exact_mut(dt)) {
                let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
                if r == [0.0; 3] {
                    self.ks.coincident(q, o);
                } else {
                    self.ks.accumulate(r, q, nrm, o);
                }
            }
        }
    }

    fn fit(&self, pinv: &Mat<f64>, check: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; pinv.nrows()];
        matmul(
            faer::MatMut::from_column_major_slice_mut(&mut out, pinv.nrows(), 1),
            Accum::Replace,
            pinv.as_ref(),
            MatRef::from_column_major_slice(check, check.len(), 1),
            1.0,
            Par::Seq,
        );
        out
    }

    /// Evaluate the sum for one density (input order); `out` receives the targets' values in
    /// input order.
    pub fn evaluate(&self, density: &[f64], out: &mut [f64]) -> Result<(), FmmError> {
        let (ds, dt) = (self.ks.density_dim(), self.ks.output_dim());
        let t = &self.tree;
        if density.len() != t.sources_sorted.len() * ds || out.len() != t.targets_sorted.len() * dt
        {
            return Err(FmmError::Shape(
                "density or output length does not match the tree".into(),
            ));
        }
        let dens: Vec<f64> = t
            .source_perm
            .iter()
            .flat_map(|&i| density[i * ds..(i + 1) * ds].iter().copied())
            .collect();
        let nb = t.nodes.len();
        let ncheck = self.surf.len() * dt;
        let check_pts = |b: usize, r: f64| -> Vec<[f64; 3]> { self.surface(b, r).collect() };
        // Upward pass: children before parents (children have larger indices).
        let mut upward: Vec<Vec<f64>> = vec![Vec::new(); nb];
        for b in (0..nb).rev() {
            let node = &t.nodes[b];
            if node.sources.is_empty() {
                continue;
            }
            let pts = check_pts(b, UP_CHECK);
            let mut check = vec![0.0; ncheck];
            if node.is_leaf() {
                self.sources_to_points(b, &dens, &pts, &mut check);
            } else {
                for &c in &node.children {
                    if !upward[c].is_empty() {
                        self.equiv_to_points(c, INNER, &upward[c], &pts, &mut check);
                    }
                }
            }
            upward[b] = self.fit(&self.up[node.level as usize], &check);
        }
        // Downward pass, level by level (boxes of one level in parallel).
        let mut downward: Vec<Vec<f64>> = vec![Vec::new(); nb];
        let max_level = t.depth();
        for level in 2..max_level {
            let ids: Vec<usize> = (0..nb)
                .filter(|&b| t.nodes[b].level == level && !t.nodes[b].targets.is_empty())
                .collect();
            let results: Vec<(usize, Vec<f64>)> = ids
                .par_iter()
                .map(|&b| {
                    let node = &t.nodes[b];
                    let pts = check_pts(b, INNER);
                    let mut check = vec![0.0; ncheck];
                    let p = node.parent.expect("level ≥ 2 has a parent");
                    if !downward[p].is_empty() {
                        self.equiv_to_points(p, DOWN_EQUIV, &downward[p], &pts, &mut check);
                    }
                    for &a in &self.lists.v[b] {
                        if !upward[a].is_empty() {
                            self.equiv_to_points(a, INNER, &upward[a], &pts, &mut check);
                        }
                    }
                    for &a in &self.lists.x[b] {
                        self.sources_to_points(a, &dens, &pts, &mut check);
                    }
                    (b, self.fit(&self.down[level as usize], &check))
                })
                .collect();
            for (b, d) in results {
                downward[b] = d;
            }
        }
        // Leaves: L2P + P2P (U) + M2P (W), leaves in parallel.
        let leaves: Vec<usize> = (0..nb)
            .filter(|&b| t.nodes[b].is_leaf() && !t.nodes[b].targets.is_empty())
            .collect();
        let results: Vec<(usize, Vec<f64>)> = leaves
            .par_iter()
            .map(|&b| {
                let node = &t.nodes[b];
                let pts = &t.targets_sorted[node.targets.clone()];
                let mut vals = vec![0.0; pts.len() * dt];
                if !downward[b].is_empty() {
                    self.equiv_to_points(b, DOWN_EQUIV, &downward[b], pts, &mut vals);
                }
                for &a in &self.lists.u[b] {
                    self.sources_to_points(a, &dens, pts, &mut vals);
                }
                for &a in &self.lists.w[b] {
                    if !upward[a].is_empty() {
                        self.equiv_to_points(a, INNER, &upward[a], pts, &mut vals);
                    }
                }
                (b, vals)
            })
            .collect();
        for (b, vals) in results {
            for (k, i) in t.nodes[b].targets.clone().enumerate() {
                let dst = t.target_perm[i];
                out[dst * dt..(dst + 1) * dt].copy_from_slice(&vals[k * dt..(k + 1) * dt]);
            }
        }
        Ok(())
    }
}
