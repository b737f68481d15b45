//! Direct `O(N M)` summation: the reference for the FMM and the exact path of `mobo fmm
//! --direct`. The kernel is applied pair by pair (serial); rayon splits the targets.

use rayon::prelude::*;

use super::kernels::Kernel;
use super::FmmError;

/// Point data of one sum. `sources`, `targets`: points; `density`: `density_dim` values per
/// source; `normals`: one per source when the kernel needs them.
#[derive(Clone, Copy, Debug)]
pub struct SumInput<'a> {
    /// Source points.
    pub sources: &'a [[f64; 3]],
    /// Densities, `density_dim` values per source, source-major.
    pub density: &'a [f64],
    /// Source orientations (double-layer kernels), one per source.
    pub normals: Option<&'a [[f64; 3]]>,
    /// Target points.
    pub targets: &'a [[f64; 3]],
}

/// Check the sizes of a sum's inputs against the kernel.
pub fn validate<K: Kernel + ?Sized>(k: &K, input: &SumInput) -> Result<(), FmmError> {
    let n = input.sources.len();
    if input.density.len() != n * k.density_dim() {
        return Err(FmmError::Shape(format!(
            "{} needs {} density values per source: {} sources but {} values",
            k.name(),
            k.density_dim(),
            n,
            input.density.len()
        )));
    }
    match (k.needs_normals(), input.normals) {
        (true, None) => return Err(FmmError::Shape(format!("{} needs normals", k.name()))),
        (true, Some(nm)) if nm.len() != n => {
            return Err(FmmError::Shape(format!(
                "{} normals for {} sources",
                nm.len(),
                n
            )))
        }
        _ => {}
    }
    Ok(())
}

/// `out[i·output_dim ..]` = the sum over all sources at target `i`.
pub fn direct_sum<K: Kernel + ?Sized>(
    k: &K,
    input: &SumInput,
    out: &mut [f64],
) -> Result<(), FmmError> {
    validate(k, input)?;
    let (dd, od) = (k.density_dim(), k.output_dim());
    if out.len() != input.targets.len() * od {
        return Err(FmmError::Shape(format!(
            "output has {} values, expected {}",
            out.len(),
            input.targets.len() * od
        )));
    }
    out.par_chunks_mut(od)
        .zip(input.targets.par_iter())
        .for_each(|(o, x)| {
            o.fill(0.0);
            for (j, y) in input.sources.iter().enumerate() {
                let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
                let q = &input.density[j * dd..(j + 1) * dd];
                if r == [0.0; 3] {
                    k.coincident(q, o);
                } else {
                    let n = input.normals.map_or([0.0; 3], |nm| nm[j]);
                    k.accumulate(r, q, n, o);
                }
            }
        });
    Ok(())
}
