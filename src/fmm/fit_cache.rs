//! An on-disk cache of the KIFMM fits (the truncated-SVD pseudo-inverses of [`super::operators`]).
//!
//! The two fits of an equivalent kernel and order are the only `O(n³)` part of the setup:
//! at 9 digits for the Stokes kernels (order 15, `n = 3·1178` unknowns per surface) they take
//! about a minute of one core, and every MPI rank needs the same two matrices. PVFMM keeps its
//! precomputed operators in a file for the same reason. Setting the environment variable
//! `MOBO_OPERATOR_CACHE` to a directory makes [`super::Fmm`] store each fit there after
//! computing it and load it on later setups (in this process, later runs, other ranks).
//!
//! A file holds one [`Pinv`] and is named by a hash of everything the fit depends on (kernel,
//! order, truncation, surface radii): a file that does not match its key, is truncated, or
//! fails its checksum is ignored and rewritten. Files are written atomically (a temporary name,
//! then a rename), so ranks that compute the same fit at once leave one whole file.
//!
//! ```
//! use mobo::fmm::fit_cache::{load, store};
//! use mobo::fmm::operators::Pinv;
//! let dir = std::env::temp_dir().join(format!("mobo-fit-doc-{}", std::process::id()));
//! let a = faer::Mat::from_fn(3, 3, |i, j| if i == j { 2.0 } else { 0.1 });
//! let fit = Pinv::new(&a, 1e-12).unwrap();
//! store(&dir, "example", &fit).unwrap();
//! let back = load(&dir, "example").expect("stored just now");
//! assert_eq!(back.vs, fit.vs);
//! assert!(load(&dir, "another key").is_none());
//! std::fs::remove_dir_all(&dir).unwrap();
//! ```

use std::fs;
use std::path::{Path, PathBuf};

use faer::Mat;

use super::operators::Pinv;
use crate::durable::{fnv1a64, write_atomic};

const MAGIC: &[u8; 8] = b"MOBOFIT1";

/// The environment variable naming the cache directory.
pub const ENV: &str = "MOBO_OPERATOR_CACHE";

/// Errors of the fit cache (reading a file that is not there or does not match is not an
/// error: it is a miss).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FitCacheError {
    /// The directory or file could not be written.
    #[error("cannot write the operator cache file {path}: {reason}")]
    Write { path: PathBuf, reason: String },
}

/// The cache directory from [`ENV`], if set and not empty.
pub fn dir_from_env() -> Option<PathBuf> {
    std::env::var_os(ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
}

fn file_for(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("fit-{:016x}.bin", fnv1a64(key.as_bytes())))
}

fn encode(key: &str, fit: &Pinv) -> Vec<u8> {
    let mut body = Vec::new();
    for m in [&fit.vs, &fit.ut] {
        body.extend((m.nrows() as u64).to_le_bytes());
        body.extend((m.ncols() as u64).to_le_bytes());
        for j in 0..m.ncols() {
            for i in 0..m.nrows() {
                body.extend(m[(i, j)].to_le_bytes());
            }
        }
    }
    let mut out = Vec::with_capacity(body.len() + key.len() + 40);
    out.extend(MAGIC);
    out.extend((key.len() as u64).to_le_bytes());
    out.extend(key.as_bytes());
    out.extend((body.len() as u64).to_le_bytes());
    out.extend(fnv1a64(&body).to_le_bytes());
    out.extend(body);
    out
}

/// A little-endian reader that returns `None` past the end.
struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.0.len() < n {
            return None;
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Some(a)
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    fn matrix(&mut self) -> Option<Mat<f64>> {
        let (r, c) = (self.u64()? as usize, self.u64()? as usize);
        let bytes = self.take(r.checked_mul(c)?.checked_mul(8)?)?;
        let v: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
            .collect();
        Some(Mat::from_fn(r, c, |i, j| v[j * r + i]))
    }
}

fn decode(key: &str, bytes: &[u8]) -> Option<Pinv> {
    let mut r = Reader(bytes);
    if r.take(8)? != MAGIC {
        return None;
    }
    let klen = r.u64()? as usize;
    if r.take(klen)? != key.as_bytes() {
        return None;
    }
    let blen = r.u64()? as usize;
    let sum = r.u64()?;
    let body = r.take(blen)?;
    if fnv1a64(body) != sum || !r.0.is_empty() {
        return None;
    }
    let mut b = Reader(body);
    let vs = b.matrix()?;
    let ut = b.matrix()?;
    (b.0.is_empty() && vs.ncols() == ut.nrows()).then_some(Pinv { vs, ut })
}

/// The fit stored under `key` in `dir`, or `None` (no file, another key, damaged file).
pub fn load(dir: &Path, key: &str) -> Option<Pinv> {
    fs::read(file_for(dir, key))
        .ok()
        .and_then(|b| decode(key, &b))
}

/// Store `fit` under `key` in `dir` (created if missing), atomically.
pub fn store(dir: &Path, key: &str, fit: &Pinv) -> Result<(), FitCacheError> {
    let path = file_for(dir, key);
    write_atomic(&path, &encode(key, fit)).map_err(|e| FitCacheError::Write {
        path,
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit() -> Pinv {
        let a = Mat::from_fn(5, 4, |i, j| 1.0 / (1.0 + i as f64 + 2.0 * j as f64));
        Pinv::new(&a, 1e-14).unwrap()
    }

    #[test]
    fn a_stored_fit_comes_back_bit_for_bit_and_damage_is_a_miss() {
        let dir = std::env::temp_dir().join(format!("mobo-fit-cache-{}", std::process::id()));
        let f = fit();
        store(&dir, "k", &f).unwrap();
        let back = load(&dir, "k").unwrap();
        assert_eq!((back.vs, back.ut), (f.vs.clone(), f.ut.clone()));
        assert!(load(&dir, "other").is_none());
        // Flip one byte of the data, then truncate: both are misses, not errors.
        let path = file_for(&dir, "k");
        let mut bytes = fs::read(&path).unwrap();
        let last = bytes.len() - 3;
        bytes[last] ^= 0x40;
        fs::write(&path, &bytes).unwrap();
        assert!(load(&dir, "k").is_none());
        fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        assert!(load(&dir, "k").is_none());
        fs::remove_dir_all(&dir).unwrap();
    }
}
