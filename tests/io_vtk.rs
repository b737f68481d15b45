//! VTK output: `.vtp` meshes parsed back by a small independent parser (structure, exact
//! numbers, triangle areas against the analytic surface area, tension interpolated to the
//! vertices against an analytic field) and `.pvd` collections.

use std::path::PathBuf;

use mobo::io::frames::{CellFrame, FrameFormats, FrameWriter};
use mobo::io::vtk::{self, DataArray, DataValues, PolyMesh, PvdEntry};
use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::shapes;

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mobo_io_vtk_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The value of attribute `key` in the first tag starting with `<tag`.
fn attr(text: &str, tag: &str, key: &str) -> String {
    let at = text
        .find(&format!("<{tag}"))
        .unwrap_or_else(|| panic!("no <{tag}"));
    let end = at + text[at..].find('>').unwrap();
    let t = &text[at..end];
    let k = t
        .find(&format!(" {key}=\""))
        .unwrap_or_else(|| panic!("<{tag}> lacks {key}"));
    let v = &t[k + key.len() + 3..];
    v[..v.find('"').unwrap()].to_string()
}

/// The text between `<tag` and `</tag>`.
fn section<'a>(text: &'a str, tag: &str) -> &'a str {
    let at = text
        .find(&format!("<{tag}"))
        .unwrap_or_else(|| panic!("no <{tag}"));
    let end = text
        .find(&format!("</{tag}>"))
        .unwrap_or_else(|| panic!("no </{tag}>"));
    &text[at..end]
}

/// The whitespace-separated numbers of the `DataArray` named `name` inside `text`.
fn data_array(text: &str, name: &str) -> Vec<f64> {
    let at = text
        .find(&format!("Name=\"{name}\""))
        .unwrap_or_else(|| panic!("no DataArray {name}"));
    let start = at + text[at..].find('>').unwrap() + 1;
    let end = start + text[start..].find("</DataArray>").unwrap();
    text[start..end]
        .split_whitespace()
        .map(|w| {
            w.parse::<f64>()
                .unwrap_or_else(|_| panic!("bad number {w}"))
        })
        .collect()
}

/// A parsed `.vtp` mesh.
struct Parsed {
    points: Vec<[f64; 3]>,
    triangles: Vec<[usize; 3]>,
    tension: Vec<f64>,
    cell: Vec<f64>,
    cell_of_triangle: Vec<f64>,
}

fn parse_vtp(text: &str) -> Parsed {
    assert!(text.starts_with("<?xml"));
    assert_eq!(attr(text, "VTKFile", "type"), "PolyData");
    let np: usize = attr(text, "Piece", "NumberOfPoints").parse().unwrap();
    let nt: usize = attr(text, "Piece", "NumberOfPolys").parse().unwrap();
    let pts = data_array(section(text, "Points"), "Points");
    assert_eq!(pts.len(), 3 * np);
    let polys = section(text, "Polys");
    let conn = data_array(polys, "connectivity");
    let offs = data_array(polys, "offsets");
    assert_eq!(offs.len(), nt);
    // Every polygon is a triangle: offsets 3, 6, 9, ...
    for (t, o) in offs.iter().enumerate() {
        assert_eq!(*o as usize, 3 * (t + 1));
    }
    assert_eq!(conn.len(), 3 * nt);
    let triangles: Vec<[usize; 3]> = conn
        .chunks(3)
        .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize])
        .collect();
    assert!(triangles.iter().flatten().all(|&v| v < np));
    let pd = section(text, "PointData");
    let cd = section(text, "CellData");
    let tension = if pd.contains("Name=\"tension\"") {
        data_array(pd, "tension")
    } else {
        Vec::new()
    };
    let cell = if pd.contains("Name=\"cell\"") {
        data_array(pd, "cell")
    } else {
        Vec::new()
    };
    let cell_of_triangle = if cd.contains("Name=\"cell\"") {
        data_array(cd, "cell")
    } else {
        Vec::new()
    };
    Parsed {
        points: pts.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
        triangles,
        tension,
        cell,
        cell_of_triangle,
    }
}

fn tri_area(p: &[[f64; 3]], t: [usize; 3]) -> f64 {
    let (a, b, c) = (p[t[0]], p[t[1]], p[t[2]]);
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let w = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    0.5 * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt()
}

/// Outward orientation: the signed volume `Σ a·(b×c)/6` of a closed mesh around `centre`.
fn signed_volume(p: &[[f64; 3]], tris: &[[usize; 3]], centre: [f64; 3]) -> f64 {
    tris.iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| [0, 1, 2].map(|k| p[i][k] - centre[k]));
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum()
}

/// Surface area of the ellipsoid with semi-axes `a, b, c` by a fine midpoint rule on
/// `|X_θ × X_φ|` (independent of the SH code).
fn ellipsoid_area(a: f64, b: f64, c: f64) -> f64 {
    let (nt, np) = (2000, 2000);
    let (dt, dp) = (
        std::f64::consts::PI / nt as f64,
        2.0 * std::f64::consts::PI / np as f64,
    );
    let mut s = 0.0;
    for i in 0..nt {
        let t = (i as f64 + 0.5) * dt;
        let (st, ct) = t.sin_cos();
        for j in 0..np {
            let f = (j as f64 + 0.5) * dp;
            let (sf, cf) = f.sin_cos();
            // n = X_θ × X_φ = sinθ (bc sinθ cosφ, ac sinθ sinφ, ab cosθ)
            let n = [b * c * st * cf, a * c * st * sf, a * b * ct];
            s += st * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        }
    }
    s * dt * dp
}

#[test]
fn polydata_round_trips_exactly() {
    let d = tmpdir("roundtrip");
    let mesh = PolyMesh {
        points: vec![
            [0.0, 0.0, 0.0],
            [1.0, -0.0, 1e-300],
            [0.1, 0.2, 0.3],
            [-std::f64::consts::PI, 6.02e23, f64::MIN_POSITIVE / 4.0],
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3], [1, 3, 2]],
        point_data: vec![
            DataArray::scalars("tension <σ> & \"x\"", vec![1.5, -2.25, 1.0 / 3.0, 7e-12]),
            DataArray {
                name: "velocity".into(),
                components: 3,
                values: DataValues::Float64((0..12).map(|i| i as f64 * 0.1).collect()),
            },
        ],
        cell_data: vec![DataArray::ints("cell", vec![4, 5, -6])],
    };
    let path = d.join("m.vtp");
    vtk::write_polydata(&path, &mesh).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let p = parse_vtp(&text);
    assert_eq!(p.points.len(), 4);
    for (a, b) in p.points.iter().zip(&mesh.points) {
        for k in 0..3 {
            assert_eq!(a[k].to_bits(), b[k].to_bits(), "{a:?} vs {b:?}");
        }
    }
    assert_eq!(p.triangles, mesh.triangles);
    assert_eq!(p.cell_of_triangle, vec![4.0, 5.0, -6.0]);
    // The escaped name is the active scalar and its values read back exactly.
    assert_eq!(
        attr(&text, "PointData", "Scalars"),
        "tension &lt;σ&gt; &amp; &quot;x&quot;"
    );
    let t = data_array(&text, "tension &lt;σ&gt; &amp; &quot;x&quot;");
    assert_eq!(t, vec![1.5, -2.25, 1.0 / 3.0, 7e-12]);
    let v = data_array(&text, "velocity");
    assert_eq!(v.len(), 12);
    assert!(text.contains("Name=\"velocity\" NumberOfComponents=\"3\""));
    // No temporary file is left.
    assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1);

    // Inconsistent meshes are errors naming the file, and nothing is written.
    let mut bad = mesh.clone();
    bad.triangles.push([0, 1, 4]);
    let e = vtk::write_polydata(&d.join("bad.vtp"), &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad.vtp") && e.contains("triangle 3"), "{e}");
    let mut bad = mesh.clone();
    bad.point_data[1].components = 2;
    let e = vtk::write_polydata(&d.join("bad.vtp"), &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("velocity") && e.contains("12 values"), "{e}");
    assert!(!d.join("bad.vtp").exists());
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn pvd_lists_frames_with_exact_times() {
    let d = tmpdir("pvd");
    let entries = vec![
        PvdEntry {
            time: 0.0,
            file: "frame_00000.vtp".into(),
        },
        PvdEntry {
            time: 0.1 + 0.2,
            file: "frame_00001.vtp".into(),
        },
        PvdEntry {
            time: 1e-7,
            file: "a&b.vtp".into(),
        },
    ];
    let path = d.join("frames.pvd");
    vtk::write_pvd(&path, &entries).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(attr(&text, "VTKFile", "type"), "Collection");
    let sets: Vec<&str> = text.split("<DataSet").skip(1).collect();
    assert_eq!(sets.len(), 3);
    for (s, e) in sets.iter().zip(&entries) {
        let s = format!("<DataSet{s}");
        let t: f64 = attr(&s, "DataSet", "timestep").parse().unwrap();
        assert_eq!(t.to_bits(), e.time.to_bits());
        assert_eq!(attr(&s, "DataSet", "file"), e.file.replace('&', "&amp;"));
    }
    std::fs::remove_dir_all(&d).unwrap();
}

/// Write one frame of a sphere (radius `r`, centre `(-3,0,0)`, tension `x·y` relative to its
/// centre) and an ellipsoid (axes `axes`, centre `(4,0,1)`, tension `z`) with `k` subdivisions,
/// and parse the `.vtp` back.
fn sphere_and_ellipsoid(name: &str, k: u32, r: f64, axes: [f64; 3]) -> (Parsed, usize) {
    let p = 8;
    let sht = ShTransform::new(p).unwrap();
    let np = sht.n_points();
    let mut sph = shapes::sphere(p, r).unwrap();
    sph.translate([-3.0, 0.0, 0.0]);
    let mut ell = shapes::ellipsoid(p, axes).unwrap();
    ell.translate([4.0, 0.0, 1.0]);
    let xs = sph.grid_positions(&sht).unwrap();
    let xe = ell.grid_positions(&sht).unwrap();
    let ts: Vec<f64> = (0..np).map(|j| (xs[j] + 3.0) * xs[np + j]).collect();
    let te: Vec<f64> = xe[2 * np..].to_vec();
    let d = tmpdir(name);
    let mut w = FrameWriter::new(
        &d,
        FrameFormats {
            npy: false,
            hdf5: false,
            vtp: Some(k),
        },
    )
    .unwrap();
    let cells = [
        CellFrame {
            order: p,
            coefs: sph.coefs(),
            positions: &xs,
            tension: &ts,
        },
        CellFrame {
            order: p,
            coefs: ell.coefs(),
            positions: &xe,
            tension: &te,
        },
    ];
    w.write_frame(0, 0.0, &cells).unwrap();
    w.finish().unwrap();
    assert!(!d.join("frames").exists(), "npy output was not asked for");
    let text = std::fs::read_to_string(d.join("vtk/frame_00000.vtp")).unwrap();
    std::fs::remove_dir_all(&d).unwrap();
    (parse_vtp(&text), 10 * 4usize.pow(k) + 2)
}

#[test]
fn cell_meshes_have_the_surface_area_and_the_tension_field() {
    let r = 1.3;
    let axes = [1.5, 1.0, 0.7];
    let exact = [
        4.0 * std::f64::consts::PI * r * r,
        ellipsoid_area(axes[0], axes[1], axes[2]),
    ];
    let mut errors = Vec::new();
    for k in [2u32, 3, 4] {
        let (m, nv) = sphere_and_ellipsoid(&format!("areas{k}"), k, r, axes);
        let nt = 20 * 4usize.pow(k);
        assert_eq!(m.points.len(), 2 * nv);
        assert_eq!(m.triangles.len(), 2 * nt);
        // Cell ids: the first nv points / nt triangles are cell 0, then cell 1; triangles stay
        // within their cell.
        for (i, c) in m.cell.iter().enumerate() {
            assert_eq!(*c as usize, i / nv);
        }
        for (t, c) in m.cell_of_triangle.iter().enumerate() {
            assert_eq!(*c as usize, t / nt);
            assert!(m.triangles[t].iter().all(|&v| v / nv == t / nt));
        }
        // Vertices lie on the analytic surfaces.
        for (i, x) in m.points.iter().enumerate() {
            let g = if i < nv {
                ((x[0] + 3.0).powi(2) + x[1] * x[1] + x[2] * x[2]) / (r * r)
            } else {
                ((x[0] - 4.0) / axes[0]).powi(2)
                    + (x[1] / axes[1]).powi(2)
                    + ((x[2] - 1.0) / axes[2]).powi(2)
            };
            assert!((g - 1.0).abs() < 1e-12, "vertex {i}: {g}");
        }
        // The tension is the analytic field at the vertices.
        for (i, x) in m.points.iter().enumerate() {
            let want = if i < nv { (x[0] + 3.0) * x[1] } else { x[2] };
            assert!(
                (m.tension[i] - want).abs() < 1e-12,
                "vertex {i}: tension {} vs {want}",
                m.tension[i]
            );
        }
        let mut err = [0.0; 2];
        for (c, centre) in [[-3.0, 0.0, 0.0], [4.0, 0.0, 1.0]].into_iter().enumerate() {
            let tris = &m.triangles[c * nt..(c + 1) * nt];
            let area: f64 = tris.iter().map(|&t| tri_area(&m.points, t)).sum();
            err[c] = (exact[c] - area) / exact[c];
            // Inscribed polyhedron: a little less area than the surface.
            assert!(err[c] > 0.0 && err[c] < 0.05, "k={k} cell {c}: {}", err[c]);
            assert!(
                signed_volume(&m.points, tris, centre) > 0.0,
                "outward triangles"
            );
        }
        errors.push(err);
    }
    // Second-order convergence: each subdivision halves h, so the area error drops ~4×.
    for c in 0..2 {
        for w in errors.windows(2) {
            let ratio = w[0][c] / w[1][c];
            assert!(
                (3.5..4.5).contains(&ratio),
                "cell {c}: ratio {ratio} ({errors:?})"
            );
        }
    }
    assert!(errors[2][0] < 2e-3 && errors[2][1] < 3e-3, "{errors:?}");
}
