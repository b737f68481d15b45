//! VTK XML PolyData (`.vtp`) triangle meshes and ParaView collections (`.pvd`).
//!
//! # `.vtp`
//!
//! One `<Piece>` of a `PolyData` file (`version="1.0"`, `header_type="UInt64"`) holds the whole
//! [`PolyMesh`]: `<Points>` (one `Float64` array of 3 components), `<Polys>` (`Int64` arrays
//! `connectivity`, the three vertex indices of every triangle, and `offsets`, `3, 6, 9, …`), and
//! any number of named `<PointData>` / `<CellData>` arrays (`Float64` or `Int32`). The first
//! point-data array is declared the active scalar. All arrays are written in the `ascii`
//! format, one point / triangle / tuple per line; floating-point values are printed in Rust's
//! shortest round-trip scientific notation (`{:e}`, e.g. `-1.25e-3`), so the text reads back
//! to exactly the same `f64` (non-finite values print as `NaN`, `inf`, `-inf`).
//!
//! # `.pvd`
//!
//! A `Collection` with one `<DataSet timestep="t" group="" part="0" file="…"/>` per frame;
//! ParaView opens it as a time series. File names are relative to the `.pvd`'s directory.
//!
//! Both are written atomically ([`write_atomic`]).

use std::fmt::Write as _;
use std::path::Path;

use super::{write_atomic, IoError};

/// The values of a data array.
#[derive(Clone, Debug, PartialEq)]
pub enum DataValues {
    /// `Float64` values.
    Float64(Vec<f64>),
    /// `Int32` values.
    Int32(Vec<i32>),
}

impl DataValues {
    fn len(&self) -> usize {
        match self {
            DataValues::Float64(v) => v.len(),
            DataValues::Int32(v) => v.len(),
        }
    }
}

/// A named point- or cell-data array: `components` values per point (or triangle).
#[derive(Clone, Debug, PartialEq)]
pub struct DataArray {
    /// Name shown in ParaView.
    pub name: String,
    /// Values per tuple (1 for a scalar, 3 for a vector).
    pub components: usize,
    /// `components × (points or triangles)` values, tuple after tuple.
    pub values: DataValues,
}

impl DataArray {
    /// A scalar `Float64` array.
    pub fn scalars(name: impl Into<String>, values: Vec<f64>) -> Self {
        DataArray {
            name: name.into(),
            components: 1,
            values: DataValues::Float64(values),
        }
    }

    /// A scalar `Int32` array.
    pub fn ints(name: impl Into<String>, values: Vec<i32>) -> Self {
        DataArray {
            name: name.into(),
            components: 1,
            values: DataValues::Int32(values),
        }
    }
}

/// A triangle mesh with point and cell data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PolyMesh {
    /// Vertex positions.
    pub points: Vec<[f64; 3]>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[usize; 3]>,
    /// Arrays with one tuple per point.
    pub point_data: Vec<DataArray>,
    /// Arrays with one tuple per triangle.
    pub cell_data: Vec<DataArray>,
}

/// One frame of a `.pvd` collection.
#[derive(Clone, Debug, PartialEq)]
pub struct PvdEntry {
    /// The frame's time.
    pub time: f64,
    /// The frame's file, relative to the `.pvd`.
    pub file: String,
}

/// Escape text for an XML attribute value.
fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

fn write_data_array(
    out: &mut String,
    a: &DataArray,
    tuples: usize,
    what: &str,
) -> Result<(), String> {
    if a.components == 0 {
        return Err(format!("{what} array '{}' has 0 components", a.name));
    }
    if a.values.len() != a.components * tuples {
        return Err(format!(
            "{what} array '{}' has {} values; {} {what}s × {} components need {}",
            a.name,
            a.values.len(),
            tuples,
            a.components,
            a.components * tuples
        ));
    }
    let ty = match a.values {
        DataValues::Float64(_) => "Float64",
        DataValues::Int32(_) => "Int32",
    };
    let _ = writeln!(
        out,
        "        <DataArray type=\"{ty}\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"ascii\">",
        xml_escape(&a.name),
        a.components
    );
    let k = a.components;
    match &a.values {
        DataValues::Float64(v) => {
            for t in v.chunks(k) {
                out.push_str("         ");
                for x in t {
                    let _ = write!(out, " {x:e}");
                }
                out.push('\n');
            }
        }
        DataValues::Int32(v) => {
            for t in v.chunks(k) {
                out.push_str("         ");
                for x in t {
                    let _ = write!(out, " {x}");
                }
                out.push('\n');
            }
        }
    }
    out.push_str("        </DataArray>\n");
    Ok(())
}

/// The `.vtp` text of a mesh; an error describes an inconsistent mesh (a triangle index out of
/// range, a data array of the wrong length).
pub fn encode_polydata(mesh: &PolyMesh) -> Result<String, String> {
    let np = mesh.points.len();
    let nt = mesh.triangles.len();
    if let Some((t, tri)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, tri)| tri.iter().any(|&v| v >= np))
    {
        return Err(format!(
            "triangle {t} has vertex indices {tri:?} but the mesh has {np} points"
        ));
    }
    let mut out = String::with_capacity(64 * (np + nt) + 512);
    out.push_str("<?xml version=\"1.0\"?>\n");
    out.push_str(
        "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n",
    );
    out.push_str("  <PolyData>\n");
    let _ = writeln!(
        out,
        "    <Piece NumberOfPoints=\"{np}\" NumberOfVerts=\"0\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"{nt}\">"
    );
    match mesh.point_data.first() {
        Some(a) => {
            let _ = writeln!(out, "      <PointData Scalars=\"{}\">", xml_escape(&a.name));
        }
        None => out.push_str("      <PointData>\n"),
    }
    for a in &mesh.point_data {
        write_data_array(&mut out, a, np, "point")?;
    }
    out.push_str("      </PointData>\n");
    out.push_str("      <CellData>\n");
    for a in &mesh.cell_data {
        write_data_array(&mut out, a, nt, "triangle")?;
    }
    out.push_str("      </CellData>\n");
    out.push_str("      <Points>\n");
    out.push_str(
        "        <DataArray type=\"Float64\" Name=\"Points\" NumberOfComponents=\"3\" format=\"ascii\">\n",
    );
    for p in &mesh.points {
        let _ = writeln!(out, "          {:e} {:e} {:e}", p[0], p[1], p[2]);
    }
    out.push_str("        </DataArray>\n");
    out.push_str("      </Points>\n");
    out.push_str("      <Polys>\n");
    out.push_str("        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for t in &mesh.triangles {
        let _ = writeln!(out, "          {} {} {}", t[0], t[1], t[2]);
    }
    out.push_str("        </DataArray>\n");
    out.push_str("        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for t in 0..nt {
        let _ = writeln!(out, "          {}", 3 * (t + 1));
    }
    out.push_str("        </DataArray>\n");
    out.push_str("      </Polys>\n");
    out.push_str("    </Piece>\n");
    out.push_str("  </PolyData>\n");
    out.push_str("</VTKFile>\n");
    Ok(out)
}

/// Write a mesh as `.vtp` to `path` atomically.
pub fn write_polydata(path: &Path, mesh: &PolyMesh) -> Result<(), IoError> {
    let text = encode_polydata(mesh).map_err(|message| IoError::Vtk {
        path: path.to_path_buf(),
        message,
    })?;
    write_atomic(path, text.as_bytes())
}

/// The `.pvd` text of a collection.
pub fn encode_pvd(entries: &[PvdEntry]) -> String {
    let mut out = String::with_capacity(96 * entries.len() + 256);
    out.push_str("<?xml version=\"1.0\"?>\n");
    out.push_str("<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n");
    out.push_str("  <Collection>\n");
    for e in entries {
        let _ = writeln!(
            out,
            "    <DataSet timestep=\"{:e}\" group=\"\" part=\"0\" file=\"{}\"/>",
            e.time,
            xml_escape(&e.file)
        );
    }
    out.push_str("  </Collection>\n");
    out.push_str("</VTKFile>\n");
    out
}

/// Write a `.pvd` collection to `path` atomically.
pub fn write_pvd(path: &Path, entries: &[PvdEntry]) -> Result<(), IoError> {
    write_atomic(path, encode_pvd(entries).as_bytes())
}

/// Write the `.pvd` collection of a time series to `path` atomically: frame `i` at `times[i]`
/// in the file `file(i)`.
pub fn write_pvd_series(
    path: &Path,
    times: &[f64],
    file: impl Fn(usize) -> String,
) -> Result<(), IoError> {
    let entries: Vec<PvdEntry> = times
        .iter()
        .enumerate()
        .map(|(i, &time)| PvdEntry {
            time,
            file: file(i),
        })
        .collect();
    write_pvd(path, &entries)
}
