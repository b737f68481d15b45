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
    let (shape, start) = decode_header(bytes)?;
    let count: usize = shape.iter().product();
    let data = &bytes[start..];
    if data.len() != 8 * count {
        return Err(format!(
            "shape {shape:?} needs {} bytes of data, file has {}",
            8 * count,
            data.len()
        ));
    }
    Ok((shape, values(data)))
}

fn values(data: &[u8]) -> Vec<f64> {
    data.chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8")))
        .collect()
}

/// Read rows `rows` (along the first axis) of a little-endian `float64` array in C order,
/// without reading the rest of the file (each MPI rank reads its own share):
/// `(shape of the whole array, data of the rows)`. Rows past the end are an error.
pub fn read_f64_rows(
    path: &Path,
    rows: std::ops::Range<usize>,
) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    use std::io::{Read, Seek, SeekFrom};
    let file_err = |source| IoError::File {
        path: path.to_path_buf(),
        source,
    };
    let npy_err = |message: String| IoError::Npy {
        path: path.to_path_buf(),
        message,
    };
    let mut f = std::fs::File::open(path).map_err(file_err)?;
    let len = f.metadata().map_err(file_err)?.len() as usize;
    let mut head = vec![0u8; len.min(12)];
    f.read_exact(&mut head).map_err(file_err)?;
    let hlen = match head.get(6) {
        Some(1) if head.len() >= 10 => u16::from_le_bytes([head[8], head[9]]) as usize + 10,
        Some(2 | 3) if head.len() >= 12 => {
            u32::from_le_bytes([head[8], head[9], head[10], head[11]]) as usize + 12
        }
        _ => {
            let e = decode_header(&head)
                .err()
                .unwrap_or("truncated header".into());
            return Err(npy_err(e));
        }
    };
    let mut head = vec![0u8; hlen.min(len)];
    f.seek(SeekFrom::Start(0)).map_err(file_err)?;
    f.read_exact(&mut head).map_err(file_err)?;
    let (shape, start) = decode_header(&head).map_err(npy_err)?;
    let count: usize = shape.iter().product();
    if len - start != 8 * count {
        return Err(npy_err(format!(
            "shape {shape:?} needs {} bytes of data, file has {}",
            8 * count,
            len - start
        )));
    }
    let n_rows = shape.first().copied().unwrap_or(1);
    if rows.start > rows.end || rows.end > n_rows {
        return Err(npy_err(format!(
            "rows {}..{} asked of an array of {n_rows} rows",
            rows.start, rows.end
        )));
    }
    let per_row = count.checked_div(n_rows).unwrap_or(0);
    f.seek(SeekFrom::Start((start + 8 * per_row * rows.start) as u64))
        .map_err(file_err)?;
    let mut data = vec![0u8; 8 * per_row * rows.len()];
    f.read_exact(&mut data).map_err(file_err)?;
    Ok((shape, values(&data)))
}

/// Parse the magic string and header: `(shape, offset of the data)`.
fn decode_header(bytes: &[u8]) -> Result<(Vec<usize>, usize), String> {
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
    Ok((shape, start + hlen))
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

    #[test]
    fn row_slices_match_the_whole_array() {
        let dir = std::env::temp_dir().join(format!("mobo-npy-rows-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.npy");
        let data: Vec<f64> = (0..30).map(|i| i as f64 * 0.25 - 2.0).collect();
        write_f64(&path, &[10, 3], &data).unwrap();
        for (a, b) in [(0, 10), (3, 7), (9, 10), (4, 4)] {
            let (shape, rows) = read_f64_rows(&path, a..b).unwrap();
            assert_eq!(shape, vec![10, 3]);
            assert_eq!(rows, data[3 * a..3 * b].to_vec());
        }
        let err = read_f64_rows(&path, 8..11).unwrap_err().to_string();
        assert!(err.contains("a.npy") && err.contains("rows 8..11"), "{err}");
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 8]).unwrap();
        let err = read_f64_rows(&path, 0..1).unwrap_err().to_string();
        assert!(err.contains("bytes of data"), "{err}");
        std::fs::write(&path, b"not numpy at all").unwrap();
        let err = read_f64_rows(&path, 0..1).unwrap_err().to_string();
        assert!(err.contains("magic"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
