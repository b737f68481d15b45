//! Checkpoint container: bit-exact round trips, every corruption reported (never a panic),
//! atomic writes, and the documented byte layout (an independent encoder below).

use std::path::{Path, PathBuf};

use mobo::io::checkpoint::{fnv1a64, Checkpoint, NamedArray, MAGIC, VERSION};
use mobo::io::{CheckpointFault, IoError};
use proptest::prelude::*;
use serde_json::json;

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mobo_io_ckpt_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Values that must survive bit for bit.
fn awkward_values() -> Vec<f64> {
    vec![
        0.0,
        -0.0,
        1.0,
        -1.0,
        f64::MIN_POSITIVE,
        f64::MIN_POSITIVE / 2.0, // subnormal
        f64::from_bits(1),       // smallest subnormal
        -f64::from_bits(0x000f_ffff_ffff_ffff),
        f64::MAX,
        f64::MIN,
        f64::EPSILON,
        1e-300,
        6.02214076e23,
        std::f64::consts::PI,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        f64::from_bits(0x7ff8_dead_beef_0001), // NaN with a payload
        f64::from_bits(0xfff0_0000_0000_0001), // negative signalling NaN
    ]
}

fn sample() -> Checkpoint {
    let mut c = Checkpoint::new(json!({
        "step": 1200,
        "dt": 0.001,
        "scene": "two cells in shear",
        "seed": [1, 2, 3],
    }));
    let v = awkward_values();
    c.push("awkward", vec![v.len()], v);
    c.push(
        "coefs",
        vec![2, 3, 4],
        (0..24).map(|i| i as f64 / 7.0).collect(),
    );
    c.push("scalar", vec![], vec![42.5]);
    c.push("empty", vec![0, 5], vec![]);
    c
}

fn same_bits(a: &Checkpoint, b: &Checkpoint) {
    assert_eq!(a.meta, b.meta);
    assert_eq!(a.arrays.len(), b.arrays.len());
    for (x, y) in a.arrays.iter().zip(&b.arrays) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.shape, y.shape);
        let xb: Vec<u64> = x.data.iter().map(|v| v.to_bits()).collect();
        let yb: Vec<u64> = y.data.iter().map(|v| v.to_bits()).collect();
        assert_eq!(xb, yb, "array {}", x.name);
    }
}

/// An encoder written from the module documentation, independent of `Checkpoint::encode`.
fn reference_encode(meta: &[u8], arrays: &[(&str, &[u64], &[f64])]) -> Vec<u8> {
    let mut body = Vec::new();
    body.extend_from_slice(b"MOBOCKPT");
    body.extend_from_slice(&1u32.to_le_bytes());
    body.extend_from_slice(&[0; 8]); // length, patched below
    body.extend_from_slice(&(meta.len() as u64).to_le_bytes());
    body.extend_from_slice(meta);
    body.extend_from_slice(&(arrays.len() as u64).to_le_bytes());
    for (name, dims, data) in arrays {
        body.extend_from_slice(&(name.len() as u32).to_le_bytes());
        body.extend_from_slice(name.as_bytes());
        body.extend_from_slice(&(dims.len() as u32).to_le_bytes());
        for d in *dims {
            body.extend_from_slice(&d.to_le_bytes());
        }
        for v in *data {
            body.extend_from_slice(&v.to_bits().to_le_bytes());
        }
    }
    let total = (body.len() + 8) as u64;
    body[12..20].copy_from_slice(&total.to_le_bytes());
    // FNV-1a 64, spelled out again.
    let mut h: u64 = 14695981039346656037;
    for &b in &body {
        h = (h ^ b as u64).wrapping_mul(1099511628211);
    }
    body.extend_from_slice(&h.to_le_bytes());
    body
}

fn fault_of(path: &Path) -> CheckpointFault {
    match Checkpoint::read(path) {
        Err(IoError::Checkpoint { path: p, fault }) => {
            assert_eq!(p, path, "the error names the file");
            fault
        }
        other => panic!("expected a checkpoint error, got {other:?}"),
    }
}

#[test]
fn fnv1a64_matches_published_vectors() {
    // Test vectors of the FNV reference (Fowler/Noll/Vo, "FNV-1a 64").
    assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
    assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
    assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
}

#[test]
fn round_trip_is_bit_exact_and_layout_is_as_documented() {
    let d = tmpdir("roundtrip");
    let path = d.join("state.ckpt");
    let c = sample();
    c.write(&path).unwrap();
    let back = Checkpoint::read(&path).unwrap();
    same_bits(&c, &back);
    assert_eq!(back.get("scalar").unwrap().data, vec![42.5]);
    assert_eq!(back.get("coefs").unwrap().shape, vec![2, 3, 4]);
    assert!(back.get("missing").is_none());

    // The bytes are those of the documented layout.
    let meta = serde_json::to_vec(&c.meta).unwrap();
    let arrays: Vec<(&str, Vec<u64>, &[f64])> = c
        .arrays
        .iter()
        .map(|a| {
            (
                a.name.as_str(),
                a.shape.iter().map(|&d| d as u64).collect(),
                a.data.as_slice(),
            )
        })
        .collect();
    let arrays: Vec<(&str, &[u64], &[f64])> = arrays
        .iter()
        .map(|(n, s, v)| (*n, s.as_slice(), *v))
        .collect();
    let expected = reference_encode(&meta, &arrays);
    assert_eq!(std::fs::read(&path).unwrap(), expected);
    assert_eq!(&expected[..8], &MAGIC);
    assert_eq!(VERSION, 1);

    // No temporary file is left next to it.
    let names: Vec<String> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, vec!["state.ckpt".to_string()]);
    // Overwriting replaces the file whole.
    let mut c2 = c.clone();
    c2.arrays.truncate(1);
    c2.write(&path).unwrap();
    same_bits(&c2, &Checkpoint::read(&path).unwrap());
    assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1);
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn every_flipped_byte_is_detected() {
    let c = sample();
    let bytes = c.encode().unwrap();
    for i in 0..bytes.len() {
        for bit in [0x01u8, 0x80] {
            let mut b = bytes.clone();
            b[i] ^= bit;
            let r = Checkpoint::decode(&b);
            assert!(
                r.is_err(),
                "flipping bit {bit:#x} of byte {i} went unnoticed"
            );
            // Past the fixed header, a flip is a checksum mismatch.
            if i >= 20 {
                assert!(
                    matches!(r, Err(CheckpointFault::Checksum { .. })),
                    "byte {i}: {r:?}"
                );
            }
        }
    }
    // Named cases, through a file.
    let d = tmpdir("flip");
    let path = d.join("c.ckpt");
    let mut b = bytes.clone();
    b[100] ^= 0x10;
    std::fs::write(&path, &b).unwrap();
    let f = fault_of(&path);
    assert!(matches!(f, CheckpointFault::Checksum { .. }), "{f:?}");
    let msg = Checkpoint::read(&path).unwrap_err().to_string();
    assert!(
        msg.contains("c.ckpt") && msg.contains("checksum mismatch"),
        "{msg}"
    );

    let mut b = bytes.clone();
    b[0] = b'X';
    std::fs::write(&path, &b).unwrap();
    assert_eq!(fault_of(&path), CheckpointFault::BadMagic);
    std::fs::write(&path, b"PK\x03\x04 a zip file, not a checkpoint").unwrap();
    assert_eq!(fault_of(&path), CheckpointFault::BadMagic);
    std::fs::write(&path, b"MOB").unwrap();
    assert!(matches!(
        fault_of(&path),
        CheckpointFault::Truncated { at: 3, .. }
    ));
    std::fs::write(&path, b"").unwrap();
    assert!(matches!(
        fault_of(&path),
        CheckpointFault::Truncated { at: 0, .. }
    ));

    let mut b = bytes.clone();
    b[8..12].copy_from_slice(&7u32.to_le_bytes());
    std::fs::write(&path, &b).unwrap();
    assert_eq!(
        fault_of(&path),
        CheckpointFault::UnsupportedVersion {
            found: 7,
            supported: 1
        }
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn every_truncation_is_reported_with_its_length() {
    let bytes = sample().encode().unwrap();
    for n in 0..bytes.len() {
        match Checkpoint::decode(&bytes[..n]) {
            Err(CheckpointFault::Truncated { at, .. }) => assert_eq!(at, n as u64),
            other => panic!("truncated to {n} bytes: {other:?}"),
        }
    }
    let mut long = bytes.clone();
    long.extend_from_slice(b"junk");
    assert_eq!(
        Checkpoint::decode(&long),
        Err(CheckpointFault::TrailingBytes {
            at: bytes.len() as u64,
            extra: 4
        })
    );
    let d = tmpdir("trunc");
    let path = d.join("t.ckpt");
    std::fs::write(&path, &bytes[..bytes.len() - 13]).unwrap();
    let msg = Checkpoint::read(&path).unwrap_err().to_string();
    assert!(
        msg.contains("t.ckpt") && msg.contains(&format!("truncated at byte {}", bytes.len() - 13)),
        "{msg}"
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn structural_errors_with_a_valid_checksum() {
    // Files with a good checksum but a bad structure (as a buggy or foreign writer would make).
    let bad_json = reference_encode(b"{\"step\": 3,", &[("a", &[1], &[1.0])]);
    assert!(matches!(
        Checkpoint::decode(&bad_json),
        Err(CheckpointFault::BadHeader(_))
    ));
    // Shape says 10 values, 2 are present: reported as a shape mismatch, not a panic.
    let mut short = reference_encode(b"{}", &[("x", &[10], &[1.0, 2.0])]);
    let n = short.len();
    let mut h: u64 = 14695981039346656037;
    for &b in &short[..n - 8] {
        h = (h ^ b as u64).wrapping_mul(1099511628211);
    }
    assert_eq!(short[n - 8..], h.to_le_bytes());
    match Checkpoint::decode(&short) {
        Err(CheckpointFault::ShapeMismatch {
            name,
            expected,
            found,
            ..
        }) => {
            assert_eq!((name.as_str(), expected, found), ("x", 10, 2));
        }
        other => panic!("{other:?}"),
    }
    // A huge dimension must not allocate or overflow.
    short = reference_encode(b"{}", &[("x", &[u64::MAX / 2, 4], &[])]);
    assert!(Checkpoint::decode(&short).is_err());
    let dup = reference_encode(b"{}", &[("x", &[1], &[1.0]), ("x", &[1], &[2.0])]);
    assert_eq!(
        Checkpoint::decode(&dup),
        Err(CheckpointFault::DuplicateName("x".into()))
    );
    let bad_name = reference_encode(b"{}", &[("\u{e9}", &[1], &[1.0])]);
    let mut b = bad_name.clone();
    // Replace the 2-byte UTF-8 name with invalid bytes and re-sign.
    let at = 20 + b[20..].iter().position(|&x| x == 0xc3).unwrap();
    b[at] = 0xff;
    let n = b.len();
    let mut h: u64 = 14695981039346656037;
    for &x in &b[..n - 8] {
        h = (h ^ x as u64).wrapping_mul(1099511628211);
    }
    b[n - 8..].copy_from_slice(&h.to_le_bytes());
    assert!(matches!(
        Checkpoint::decode(&b),
        Err(CheckpointFault::Malformed(_))
    ));
}

#[test]
fn inconsistent_checkpoints_are_refused_on_write() {
    let d = tmpdir("refuse");
    let path = d.join("bad.ckpt");
    let mut c = Checkpoint::new(json!({}));
    c.push("x", vec![2, 3], vec![0.0; 5]);
    match c.write(&path) {
        Err(IoError::Checkpoint {
            path: p,
            fault:
                CheckpointFault::ShapeMismatch {
                    expected, found, ..
                },
        }) => {
            assert_eq!(p, path);
            assert_eq!((expected, found), (6, 5));
        }
        other => panic!("{other:?}"),
    }
    let mut c = Checkpoint::new(json!({}));
    c.arrays.push(NamedArray::new("y", vec![1], vec![1.0]));
    c.arrays.push(NamedArray::new("y", vec![1], vec![1.0]));
    assert!(matches!(
        c.write(&path),
        Err(IoError::Checkpoint {
            fault: CheckpointFault::DuplicateName(_),
            ..
        })
    ));
    // Nothing was written.
    assert_eq!(std::fs::read_dir(&d).unwrap().count(), 0);
    // A missing file names itself.
    let msg = Checkpoint::read(&d.join("nope.ckpt"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("nope.ckpt"), "{msg}");
    std::fs::remove_dir_all(&d).unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn random_arrays_round_trip_bit_exactly(
        arrays in prop::collection::vec(
            (prop::collection::vec(0usize..4, 0..4), any::<u64>()),
            0..6,
        ),
        step in any::<u32>(),
    ) {
        let mut c = Checkpoint::new(json!({ "step": step }));
        for (i, (shape, seed)) in arrays.iter().enumerate() {
            let n: usize = shape.iter().product();
            // Arbitrary bit patterns (NaNs with payloads, subnormals, infinities included).
            let mut s = *seed;
            let data = (0..n)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    f64::from_bits(s ^ (s >> 29))
                })
                .collect();
            c.push(format!("a{i}"), shape.clone(), data);
        }
        let bytes = c.encode().unwrap();
        let back = Checkpoint::decode(&bytes).unwrap();
        prop_assert_eq!(&back.meta, &c.meta);
        prop_assert_eq!(back.arrays.len(), c.arrays.len());
        for (x, y) in c.arrays.iter().zip(&back.arrays) {
            prop_assert_eq!(&x.name, &y.name);
            prop_assert_eq!(&x.shape, &y.shape);
            let xb: Vec<u64> = x.data.iter().map(|v| v.to_bits()).collect();
            let yb: Vec<u64> = y.data.iter().map(|v| v.to_bits()).collect();
            prop_assert_eq!(xb, yb);
        }
    }
}

/// Re-sign `b` (a checkpoint with its fixed header intact) with a correct length and checksum,
/// so that the structural parser behind the checksum sees the damage.
fn resign(mut b: Vec<u8>) -> Vec<u8> {
    b.truncate(b.len().saturating_sub(8));
    if b.len() >= 20 {
        let total = (b.len() + 8) as u64;
        b[12..20].copy_from_slice(&total.to_le_bytes());
    }
    let h = fnv1a64(&b);
    b.extend_from_slice(&h.to_le_bytes());
    b
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Arbitrary bytes, and arbitrary damage behind a valid checksum, give errors, not panics
    /// (nor huge allocations).
    #[test]
    fn garbage_never_panics(
        junk in prop::collection::vec(any::<u8>(), 0..200),
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(),
    ) {
        let _ = Checkpoint::decode(&junk);
        let mut prefixed = b"MOBOCKPT\x01\x00\x00\x00".to_vec();
        prefixed.extend_from_slice(&junk);
        let _ = Checkpoint::decode(&prefixed);

        let good = sample().encode().unwrap();
        let mut b = good.clone();
        for (i, v) in &edits {
            // Damage the body only (after magic, version and length).
            let k = 20 + i.index(b.len() - 28);
            b[k] = *v;
        }
        let b = resign(b);
        match Checkpoint::decode(&b) {
            // Damage that still parses (inside array values, say) gives a valid checkpoint.
            Ok(c) => prop_assert!(c.encode().is_ok()),
            Err(e) => {
                let is_checksum = matches!(e, CheckpointFault::Checksum { .. });
                prop_assert!(!is_checksum, "re-signed file reported as {:?}", e);
            }
        }
        let short = resign(good[..20 + cut.index(good.len() - 20)].to_vec());
        let _ = Checkpoint::decode(&short);
    }
}
