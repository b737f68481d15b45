//! An on-disk cache of the KIFMM fits (the truncated-SVD pseudo-inverses of [`super::operators`]).
//!
//! The two fits of an equivalent kernel and order are the only `O(n³)` part of the setup:
//! at 9 digits for the Stokes kernels (order 15, `n = 3·1178` unknowns per surface) they take
//! about a minute of one core, and every MPI rank needs the same two matrices. PVFMM keeps its
//! precomputed operators in a file for the same reason. [`super::Fmm`] stores each fit in the
//! cache directory ([`dir`]) after computing it and loads it on later setups (in this process,
//! later runs, other ranks):
//!
//! * `MOBO_OPERATOR_CACHE=DIR` names the directory; `MOBO_OPERATOR_CACHE=off` (or empty, `0`,
//!   `none`, `false`, `no`, in any case) turns the cache off;
//! * otherwise the per-user cache directory: `$XDG_CACHE_HOME/mobo/operators`, else
//!   `$HOME/.cache/mobo/operators`;
//! * [`disable`] turns it off for the process (`mobo fmm --no-cache`).
//!
//! A file holds one [`Pinv`] and is named by a hash of everything the fit depends on (kernel
//! name and its values at two fixed points, order, truncation, surface radii) and by the file
//! format ([`FORMAT`]): a file that does not
//! match its key, is truncated, or fails its checksum is ignored and rewritten. Files are
//! written atomically (a temporary name unique to the process and the call, then a rename), so
//! processes, ranks and threads that compute the same fit at once leave one whole file. A
//! directory that cannot be written is reported once ([`warn_once`]) and the run goes on.
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

use std::ffi::OsString;
use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use faer::Mat;

use super::pinv::Pinv;
use crate::durable::{fnv1a64, write_atomic};

const MAGIC: &[u8; 8] = b"MOBOFIT2";

/// The file format version (part of every file's name; the header's magic carries it too).
pub const FORMAT: u32 = 2;

/// The environment variable naming the cache directory (`off` turns the cache off).
pub const ENV: &str = "MOBO_OPERATOR_CACHE";

static DISABLED: AtomicBool = AtomicBool::new(false);

/// Errors of the fit cache (reading a file that is not there or does not match is not an
/// error: it is a miss).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FitCacheError {
    /// The directory or file could not be written.
    #[error("cannot write the operator cache file {path}: {reason}")]
    Write {
        /// The cache file.
        path: PathBuf,
        /// The operating system's message.
        reason: String,
    },
}

/// Print a store failure once per process (on standard error): the fits are then computed in
/// every run, which is slow but correct.
pub fn warn_once(e: &FitCacheError) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    WARNED.call_once(|| {
        eprintln!("mobo: warning: {e}; the FMM fits will be recomputed in every run (set {ENV}=off to silence, or {ENV}=DIR for a writable directory)");
    });
}

/// Turn the disk cache off for the rest of this process (`mobo fmm --no-cache`): fits are
/// computed, neither loaded nor stored.
pub fn disable() {
    DISABLED.store(true, Ordering::Relaxed);
}

/// The cache directory (see the module docs), or `None` when the cache is off or no
/// directory is known.
pub fn dir() -> Option<PathBuf> {
    if DISABLED.load(Ordering::Relaxed) {
        return None;
    }
    resolve(
        std::env::var_os(ENV),
        std::env::var_os("XDG_CACHE_HOME"),
        std::env::var_os("HOME"),
    )
}

/// The directory from the values of `MOBO_OPERATOR_CACHE`, `XDG_CACHE_HOME` and `HOME`.
fn resolve(
    env: Option<OsString>,
    xdg: Option<OsString>,
    home: Option<OsString>,
) -> Option<PathBuf> {
    if let Some(v) = env {
        let s = v.to_string_lossy().to_ascii_lowercase();
        let off = ["", "off", "0", "none", "false", "no"].contains(&s.as_str());
        return (!off).then(|| PathBuf::from(v));
    }
    let nonempty = |v: Option<OsString>| v.filter(|v| !v.is_empty()).map(PathBuf::from);
    nonempty(xdg)
        .or_else(|| nonempty(home).map(|h| h.join(".cache")))
        .map(|c| c.join("mobo").join("operators"))
}

fn file_for(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!(
        "fit-v{FORMAT}-{:016x}.bin",
        fnv1a64(key.as_bytes())
    ))
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
    out.extend(body_sum(&body).to_le_bytes());
    out.extend(body);
    out
}

/// The checksum of a file's body: FNV-1a over little-endian 64-bit words (the 8× fewer
/// dependent multiplies of byte-wise FNV-1a matter at 50 MB per fit), the last partial word
/// zero-padded, then the length.
fn body_sum(bytes: &[u8]) -> u64 {
    let mut h = WordSum::new();
    let words = bytes.chunks_exact(8);
    let tail = words.remainder();
    for w in words {
        h.word(u64::from_le_bytes(w.try_into().expect("8 bytes")));
    }
    if !tail.is_empty() {
        let mut last = [0u8; 8];
        last[..tail.len()].copy_from_slice(tail);
        h.word(u64::from_le_bytes(last));
    }
    h.finish(bytes.len() as u64)
}

/// FNV-1a over little-endian 64-bit words, fed a word at a time (the same sum as
/// [`body_sum`] over a body of whole words).
struct WordSum(u64);

impl WordSum {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    fn new() -> Self {
        WordSum(0xcbf2_9ce4_8422_2325)
    }
    #[inline(always)]
    fn word(&mut self, w: u64) {
        self.0 = (self.0 ^ w).wrapping_mul(Self::PRIME);
    }
    fn finish(&self, len: u64) -> u64 {
        (self.0 ^ len).wrapping_mul(Self::PRIME)
    }
}

/// Read a little-endian `u64`, summed.
fn read_u64(r: &mut impl Read, sum: Option<&mut WordSum>) -> Option<u64> {
    let mut b = [0u8; 8];
    r.read_exact(&mut b).ok()?;
    let v = u64::from_le_bytes(b);
    if let Some(h) = sum {
        h.word(v);
    }
    Some(v)
}

/// One matrix of a body (rows, columns, then the columns' values), read straight into the
/// matrix's columns; `left` is the body's bytes not yet read, so a header that claims more
/// than the file holds is a miss before anything is allocated.
fn read_matrix(r: &mut impl Read, sum: &mut WordSum, left: &mut u64) -> Option<Mat<f64>> {
    *left = left.checked_sub(16)?;
    let rows = read_u64(r, Some(sum))? as usize;
    let cols = read_u64(r, Some(sum))? as usize;
    if rows == 0 || cols == 0 {
        // No fit has an empty side; a header that says so is damage (and 0 × 2⁶⁰ reads).
        return None;
    }
    let bytes = (rows as u64).checked_mul(cols as u64)?.checked_mul(8)?;
    *left = left.checked_sub(bytes)?;
    let mut m = Mat::<f64>::zeros(rows, cols);
    for j in 0..cols {
        let col = m.col_mut(j).try_as_col_major_mut()?.as_slice_mut();
        // SAFETY: a `[f64]` is `8 · len` initialised bytes, and every bit pattern is an f64.
        let raw = unsafe {
            std::slice::from_raw_parts_mut(
                col.as_mut_ptr().cast::<u8>(),
                std::mem::size_of_val(col),
            )
        };
        r.read_exact(raw).ok()?;
        for v in col.iter_mut() {
            let w = u64::from_le(v.to_bits());
            sum.word(w);
            *v = f64::from_bits(w);
        }
    }
    Some(m)
}

/// A fit from a file of `len` bytes under `key`: `None` for another key, a wrong length, a
/// damaged body.
fn read_fit(r: &mut impl Read, key: &str, len: u64) -> Option<Pinv> {
    let mut magic = [0u8; 8];
    r.read_exact(&mut magic).ok()?;
    if &magic != MAGIC {
        return None;
    }
    let klen = read_u64(r, None)?;
    if klen != key.len() as u64 {
        return None;
    }
    let mut k = vec![0u8; key.len()];
    r.read_exact(&mut k).ok()?;
    if k != key.as_bytes() {
        return None;
    }
    let blen = read_u64(r, None)?;
    let want = read_u64(r, None)?;
    if Some(len) != blen.checked_add(32 + klen) {
        return None;
    }
    let mut sum = WordSum::new();
    let mut left = blen;
    let vs = read_matrix(r, &mut sum, &mut left)?;
    let ut = read_matrix(r, &mut sum, &mut left)?;
    (left == 0 && sum.finish(blen) == want && vs.ncols() == ut.nrows()).then_some(Pinv { vs, ut })
}

/// The fit stored under `key` in `dir`, or `None` (no file, another key, damaged file). The
/// file is read straight into the two matrices (no file-sized buffer: at 9 digits a fit is
/// 92 MB, and a fresh process pays for every page it touches).
pub fn load(dir: &Path, key: &str) -> Option<Pinv> {
    let mut f = fs::File::open(file_for(dir, key)).ok()?;
    let len = f.metadata().ok()?.len();
    read_fit(&mut f, key, len)
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

    /// A header that claims more rows than the file holds, and a file with bytes after its
    /// body, are misses (no allocation of the claimed size, no partial read).
    #[test]
    fn a_header_that_does_not_match_the_file_length_is_a_miss() {
        let dir = std::env::temp_dir().join(format!("mobo-fit-len-{}", std::process::id()));
        let f = fit();
        store(&dir, "k", &f).unwrap();
        let path = file_for(&dir, "k");
        let good = fs::read(&path).unwrap();
        // The first matrix's row count sits after magic, key length, key, body length, sum.
        let at = 8 + 8 + 1 + 8 + 8;
        let mut huge = good.clone();
        huge[at..at + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
        fs::write(&path, &huge).unwrap();
        assert!(load(&dir, "k").is_none());
        let mut longer = good.clone();
        longer.extend([0u8; 8]);
        fs::write(&path, &longer).unwrap();
        assert!(load(&dir, "k").is_none());
        fs::write(&path, &good).unwrap();
        assert_eq!(load(&dir, "k").unwrap().ut, f.ut);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn threads_storing_the_same_fit_at_once_leave_one_whole_file() {
        let dir = std::env::temp_dir().join(format!("mobo-fit-race-{}", std::process::id()));
        let f = fit();
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for _ in 0..20 {
                        store(&dir, "race", &f).unwrap();
                    }
                });
            }
            // Readers meanwhile see either nothing or the whole fit.
            s.spawn(|| {
                for _ in 0..50 {
                    if let Some(b) = load(&dir, "race") {
                        assert_eq!(b.vs, f.vs);
                    }
                }
            });
        });
        assert_eq!(load(&dir, "race").unwrap().ut, f.ut);
        let names: Vec<String> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_directory_comes_from_the_variable_then_the_user_cache() {
        let os = |s: &str| Some(OsString::from(s));
        assert_eq!(
            resolve(os("/c"), os("/x"), os("/h")),
            Some(PathBuf::from("/c"))
        );
        for off in ["off", "", "0", "none", "false", "OFF", "No"] {
            assert_eq!(resolve(os(off), os("/x"), os("/h")), None, "{off:?}");
        }
        let xdg = Some(PathBuf::from("/x/mobo/operators"));
        assert_eq!(resolve(None, os("/x"), os("/h")), xdg);
        let home = Some(PathBuf::from("/h/.cache/mobo/operators"));
        assert_eq!(resolve(None, None, os("/h")), home);
        assert_eq!(resolve(None, os(""), os("/h")), home);
        assert_eq!(resolve(None, None, None), None);
    }
}
