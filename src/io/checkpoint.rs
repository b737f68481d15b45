//! Binary checkpoints that restart a run bit-for-bit.
//!
//! A checkpoint holds caller-chosen run metadata (a JSON value) and named `f64` arrays. Arrays
//! are stored as their raw IEEE-754 bits, so every value (subnormals, `-0.0`, NaN payloads)
//! comes back identical; put everything a restart needs to reproduce a run exactly into arrays,
//! not into the JSON header (JSON numbers need not round-trip to the last bit).
//!
//! # File format (version 1)
//!
//! All integers are little-endian.
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `MOBOCKPT` |
//! | 4 | format version, `u32` (1) |
//! | 8 | total file length in bytes, `u64` (checksum included) |
//! | 8 | JSON header length `h`, `u64` |
//! | `h` | JSON header, UTF-8 |
//! | 8 | number of arrays, `u64` |
//! | per array | name length `u32`, name (UTF-8), number of dimensions `u32`, each dimension `u64`, then `∏ dims` values as `f64` bits |
//! | 8 | checksum: FNV-1a 64 ([`fnv1a64`]) of every preceding byte, `u64` |
//!
//! Reading checks, in this order: magic, version, the stored length against the file's length
//! (a shorter file is reported as truncated at its last byte), the checksum, and then the
//! structure. Every failure is an [`IoError::Checkpoint`] naming the file and the
//! [`CheckpointFault`]; no input makes the reader panic or allocate more than the file's size.
//! Array names are unique within a checkpoint.
//!
//! Writing goes through [`write_atomic`]: the file appears complete under its name or not at
//! all.

use std::path::Path;

use serde_json::Value;

use super::{write_atomic, IoError};
pub use crate::durable::fnv1a64;

/// The magic bytes that open every checkpoint.
pub const MAGIC: [u8; 8] = *b"MOBOCKPT";
/// The format version this build writes and reads.
pub const VERSION: u32 = 1;

/// What is wrong with a checkpoint.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CheckpointFault {
    /// The file does not start with [`MAGIC`].
    #[error("not a mobo checkpoint (bad magic bytes)")]
    BadMagic,
    /// A format version this build cannot read.
    #[error(
        "unsupported checkpoint format version {found} (this build reads version {supported})"
    )]
    UnsupportedVersion {
        /// The version in the file.
        found: u32,
        /// The version this build reads ([`VERSION`]).
        supported: u32,
    },
    /// The file ends before the data it announces.
    #[error("truncated at byte {at}: {needed} more bytes needed for {what}")]
    Truncated {
        /// Where the data ends: the file's length in bytes.
        at: u64,
        /// Bytes missing.
        needed: u64,
        /// What was being read.
        what: &'static str,
    },
    /// Bytes after the end announced by the file.
    #[error("{extra} unexpected bytes after the end of the checkpoint (byte {at})")]
    TrailingBytes {
        /// The announced length, where the extra bytes start.
        at: u64,
        /// Number of extra bytes.
        extra: u64,
    },
    /// The stored checksum does not match the content.
    #[error(
        "checksum mismatch (stored {stored:#018x}, computed {computed:#018x}): the file is corrupt"
    )]
    Checksum {
        /// The checksum in the file.
        stored: u64,
        /// The checksum of the bytes read.
        computed: u64,
    },
    /// An array whose data length does not match its shape.
    #[error("array '{name}': shape {shape:?} holds {expected} values but {found} were given")]
    ShapeMismatch {
        /// The array's name.
        name: String,
        /// Its shape.
        shape: Vec<usize>,
        /// `∏ shape`.
        expected: usize,
        /// Number of values given.
        found: usize,
    },
    /// The JSON header does not parse.
    #[error("bad JSON header: {0}")]
    BadHeader(String),
    /// Two arrays with the same name.
    #[error("duplicate array name '{0}'")]
    DuplicateName(String),
    /// Any other structural problem (non-UTF-8 name, impossible sizes).
    #[error("malformed: {0}")]
    Malformed(String),
}

/// A named `f64` array in C (row-major) order.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedArray {
    /// Unique name within the checkpoint.
    pub name: String,
    /// Dimensions; `data.len()` must equal their product (1 for an empty shape: a scalar).
    pub shape: Vec<usize>,
    /// The values.
    pub data: Vec<f64>,
}

impl NamedArray {
    /// An array from its name, shape and data (not checked until written).
    pub fn new(name: impl Into<String>, shape: Vec<usize>, data: Vec<f64>) -> Self {
        NamedArray {
            name: name.into(),
            shape,
            data,
        }
    }
}

/// Run metadata plus named arrays.
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// Run metadata chosen by the caller.
    pub meta: Value,
    /// The arrays, in the order they are written.
    pub arrays: Vec<NamedArray>,
}

impl Checkpoint {
    /// A checkpoint with metadata and no arrays.
    pub fn new(meta: Value) -> Self {
        Checkpoint {
            meta,
            arrays: Vec::new(),
        }
    }

    /// Append an array (checked when written).
    pub fn push(&mut self, name: impl Into<String>, shape: Vec<usize>, data: Vec<f64>) {
        self.arrays.push(NamedArray::new(name, shape, data));
    }

    /// The array called `name`.
    pub fn get(&self, name: &str) -> Option<&NamedArray> {
        self.arrays.iter().find(|a| a.name == name)
    }

    /// The file's bytes (see the module documentation).
    pub fn encode(&self) -> Result<Vec<u8>, CheckpointFault> {
        let header = serde_json::to_vec(&self.meta)
            .map_err(|e| CheckpointFault::BadHeader(e.to_string()))?;
        let mut seen = std::collections::HashSet::new();
        let mut size = 8 + 4 + 8 + 8 + header.len() + 8 + 8;
        for a in &self.arrays {
            if !seen.insert(a.name.as_str()) {
                return Err(CheckpointFault::DuplicateName(a.name.clone()));
            }
            let expected = a
                .shape
                .iter()
                .try_fold(1usize, |acc, &d| acc.checked_mul(d))
                .ok_or_else(|| {
                    CheckpointFault::Malformed(format!(
                        "array '{}': shape {:?} overflows",
                        a.name, a.shape
                    ))
                })?;
            if expected != a.data.len() {
                return Err(CheckpointFault::ShapeMismatch {
                    name: a.name.clone(),
                    shape: a.shape.clone(),
                    expected,
                    found: a.data.len(),
                });
            }
            if a.name.len() > u32::MAX as usize || a.shape.len() > u32::MAX as usize {
                return Err(CheckpointFault::Malformed(format!(
                    "array '{}': name or rank too long",
                    a.name
                )));
            }
            size += 4 + a.name.len() + 4 + 8 * a.shape.len() + 8 * a.data.len();
        }
        let mut out = Vec::with_capacity(size);
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&(size as u64).to_le_bytes());
        out.extend_from_slice(&(header.len() as u64).to_le_bytes());
        out.extend_from_slice(&header);
        out.extend_from_slice(&(self.arrays.len() as u64).to_le_bytes());
        for a in &self.arrays {
            out.extend_from_slice(&(a.name.len() as u32).to_le_bytes());
            out.extend_from_slice(a.name.as_bytes());
            out.extend_from_slice(&(a.shape.len() as u32).to_le_bytes());
            for &d in &a.shape {
                out.extend_from_slice(&(d as u64).to_le_bytes());
            }
            for v in &a.data {
                out.extend_from_slice(&v.to_bits().to_le_bytes());
            }
        }
        let sum = fnv1a64(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        debug_assert_eq!(out.len(), size);
        Ok(out)
    }

    /// Parse a checkpoint's bytes (see the module documentation for the checks).
    pub fn decode(bytes: &[u8]) -> Result<Checkpoint, CheckpointFault> {
        if bytes.len() < MAGIC.len() && !MAGIC.starts_with(bytes) {
            return Err(CheckpointFault::BadMagic);
        }
        let mut r = Reader { bytes, at: 0 };
        if r.take(8, "the magic bytes")? != MAGIC {
            return Err(CheckpointFault::BadMagic);
        }
        let version = r.u32("the format version")?;
        if version != VERSION {
            return Err(CheckpointFault::UnsupportedVersion {
                found: version,
                supported: VERSION,
            });
        }
        let total = r.u64("the file length")?;
        let len = bytes.len() as u64;
        if len < total {
            return Err(CheckpointFault::Truncated {
                at: len,
                needed: total - len,
                what: "the rest of the checkpoint",
            });
        }
        if len > total {
            return Err(CheckpointFault::TrailingBytes {
                at: total,
                extra: len - total,
            });
        }
        if total < 8 + 4 + 8 + 8 + 8 + 8 {
            return Err(CheckpointFault::Malformed(format!(
                "stored length {total} is shorter than the smallest checkpoint"
            )));
        }
        let body = &bytes[..bytes.len() - 8];
        let stored = u64::from_le_bytes(bytes[bytes.len() - 8..].try_into().expect("8 bytes"));
        let computed = fnv1a64(body);
        if stored != computed {
            return Err(CheckpointFault::Checksum { stored, computed });
        }
        // The checksum is good; parse the structure within the body.
        let mut r = Reader {
            bytes: body,
            at: r.at,
        };
        let hlen = r.len_u64("the JSON header length")?;
        let header = r.take(hlen, "the JSON header")?;
        let meta: Value = serde_json::from_slice(header)
            .map_err(|e| CheckpointFault::BadHeader(e.to_string()))?;
        let n = r.len_u64("the number of arrays")?;
        let mut arrays = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for _ in 0..n {
            let nlen = r.u32("an array name length")? as usize;
            let name = std::str::from_utf8(r.take(nlen, "an array name")?)
                .map_err(|_| CheckpointFault::Malformed("array name is not UTF-8".into()))?
                .to_string();
            if !seen.insert(name.clone()) {
                return Err(CheckpointFault::DuplicateName(name));
            }
            let ndim = r.u32("an array rank")? as usize;
            // Each dimension takes 8 bytes: bound the rank by what is left before allocating.
            if ndim > r.remaining() / 8 {
                return Err(CheckpointFault::Truncated {
                    at: r.bytes.len() as u64,
                    needed: (8 * ndim - r.remaining()) as u64,
                    what: "array dimensions",
                });
            }
            let mut shape = Vec::with_capacity(ndim);
            for _ in 0..ndim {
                shape.push(r.len_u64("an array dimension")?);
            }
            let count = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
            let count = match count {
                Some(c) if c <= r.remaining() / 8 => c,
                _ => {
                    return Err(CheckpointFault::ShapeMismatch {
                        name,
                        shape,
                        expected: count.unwrap_or(usize::MAX),
                        found: r.remaining() / 8,
                    })
                }
            };
            let raw = r.take(8 * count, "array data")?;
            let data = raw
                .chunks_exact(8)
                .map(|c| f64::from_bits(u64::from_le_bytes(c.try_into().expect("8 bytes"))))
                .collect();
            arrays.push(NamedArray { name, shape, data });
        }
        if r.remaining() != 0 {
            return Err(CheckpointFault::Malformed(format!(
                "{} bytes between the last array and the checksum",
                r.remaining()
            )));
        }
        Ok(Checkpoint { meta, arrays })
    }

    /// Write the checkpoint to `path` atomically.
    pub fn write(&self, path: &Path) -> Result<(), IoError> {
        let bytes = self.encode().map_err(|fault| IoError::Checkpoint {
            path: path.to_path_buf(),
            fault,
        })?;
        write_atomic(path, &bytes)
    }

    /// Read the checkpoint at `path`.
    pub fn read(path: &Path) -> Result<Checkpoint, IoError> {
        let bytes = std::fs::read(path).map_err(|source| IoError::File {
            path: path.to_path_buf(),
            source,
        })?;
        Checkpoint::decode(&bytes).map_err(|fault| IoError::Checkpoint {
            path: path.to_path_buf(),
            fault,
        })
    }
}

/// Bounds-checked little-endian cursor.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CheckpointFault> {
        if n > self.remaining() {
            return Err(CheckpointFault::Truncated {
                at: self.bytes.len() as u64,
                needed: (n - self.remaining()) as u64,
                what,
            });
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, CheckpointFault> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }

    fn u64(&mut self, what: &'static str) -> Result<u64, CheckpointFault> {
        Ok(u64::from_le_bytes(
            self.take(8, what)?.try_into().expect("8 bytes"),
        ))
    }

    /// A `u64` length that must fit in memory addressing.
    fn len_u64(&mut self, what: &'static str) -> Result<usize, CheckpointFault> {
        let v = self.u64(what)?;
        usize::try_from(v).map_err(|_| CheckpointFault::Malformed(format!("{what} {v} too large")))
    }
}
