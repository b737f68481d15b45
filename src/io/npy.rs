//! Minimal `.npy` (format version 1.0) reading and writing of little-endian `float64` arrays.

use std::path::Path;

use super::{write_atomic, IoError};

/// Encode a C-ordered `float64` array of the given shape.
pub fn encode_f64(shape: &[usize], data: &[f64]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "shape does not match data"
    );
    let dims = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {dims}, }}");
    // Pad so that magic (6) + version (2) + length (2) + header + '\n' is a multiple of 64.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + 8 * data.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Write a `float64` array atomically.
pub fn write_f64(path: &Path, shape: &[usize], data: &[f64]) -> Result<(), IoError> {
    write_atomic(path, &encode_f64(shape, data))
}

/// Read a little-endian `float64` array in C order: `(shape, data)`. Every malformation is an
/// error naming the file and the problem.
pub fn read_f64(path: &Path) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    let bytes = std::fs::read(path).map_err(|source| IoError::File {
        path: path.to_path_buf(),
        source,
    })?;
    decode_f64(&bytes).map_err(|message| IoError::Npy {
        path: path.to_path_buf(),
        message,
    })
}

/// Decode `.npy` bytes (see [`read_f64`]).
pub fn decode_f64(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f64>), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy file (bad magic string)".into());
    }
    let (hlen, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("truncated header".into());
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(format!("unsupported .npy format version {v}")),
    };
    let header = bytes.get(start..start + hlen).ok_or("truncated header")?;
    let header = std::str::from_utf8(header).map_err(|_| "header is not text".to_string())?;
    let field = |key: &str| -> Result<&str, String> {
        let k = format!("'{key}':");
        let at = header.find(&k).ok_or(format!("header lacks '{key}'"))?;
        Ok(header[at + k.len()..].trim_start())
    };
    let descr = field("descr")?;
    if !(descr.starts_with("'<f8'") || descr.starts_with("'f8'")) {
        let d: String = descr.chars().take_while(|c| *c != ',').collect();
        return Err(format!(
            "dtype {d} is not little-endian float64 ('<f8'); convert with .astype('<f8')"
        ));
    }
    if field("fortran_order")?.starts_with("True") {
        return Err("Fortran-ordered array; save a C-ordered one (np.ascontiguousarray)".into());
    }
    let shape_txt = field("shape")?;
    let inner = shape_txt
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or("malformed shape in header")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("malformed shape entry '{s}'"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let count: usize = shape.iter().product();
    let data = &bytes[start + hlen..];
    if data.len() != 8 * count {
        return Err(format!(
            "shape {shape:?} needs {} bytes of data, file has {}",
            8 * count,
            data.len()
        ));
    }
    let values = data
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8")))
        .collect();
    Ok((shape, values))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_malformed_files() {
        let data: Vec<f64> = (0..12).map(|i| i as f64 * 0.5 - 1.0).collect();
        let bytes = encode_f64(&[4, 3], &data);
        assert_eq!((bytes.len() - 8 * 12) % 64, 0);
        assert_eq!(decode_f64(&bytes).unwrap(), (vec![4, 3], data.clone()));
        assert_eq!(
            decode_f64(&encode_f64(&[5], &data[..5])).unwrap().0,
            vec![5]
        );
        // Overwrite a same-length piece of the header.
        let swap = |from: &str, to: &str| {
            let mut b = bytes.clone();
            let i = b
                .windows(from.len())
                .position(|w| w == from.as_bytes())
                .unwrap();
            b[i..i + to.len()].copy_from_slice(to.as_bytes());
            b
        };
        assert!(decode_f64(&swap("'<f8'", "'>f8'"))
            .unwrap_err()
            .contains("float64"));
        assert!(decode_f64(&swap("False", "True "))
            .unwrap_err()
            .contains("Fortran"));
        assert!(decode_f64(&bytes[..bytes.len() - 8])
            .unwrap_err()
            .contains("bytes of data"));
        assert!(decode_f64(b"hello world").unwrap_err().contains("magic"));
        assert!(decode_f64(&bytes[..20]).unwrap_err().contains("truncated"));
    }
}
