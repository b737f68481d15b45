//! Files that survive a crash: atomic replacement and a checksum.
//!
//! [`write_atomic`] writes to a temporary file in the target's directory, syncs it and renames
//! it over the target, so readers see the old file or the whole new one, never a part.
//! [`fnv1a64`] is the checksum the checkpoint format and the FMM's operator cache store to
//! detect damaged files. Both sit below every other module so that any layer can use them.

use std::fs;
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// Write `bytes` to `path` atomically (temporary file in the same directory, synced, then
/// renamed); creates the directory if missing.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    // Unique per process and call: threads (and ranks) writing the same file at once each
    // rename a whole file of their own.
    static CALLS: AtomicU64 = AtomicU64::new(0);
    let call = CALLS.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(".{name}.tmp{}.{call}", std::process::id()));
    let written = fs::File::create(&tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    let result = written.and_then(|_| fs::rename(&tmp, path));
    if result.is_err() {
        // Leave no temporary behind (their names are unique, so they would pile up).
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// FNV-1a, 64 bits (offset basis `0xcbf29ce484222325`, prime `0x100000001b3`).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}
