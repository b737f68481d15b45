//! FrameWriter: two frames of two cells, read back through `npy::read_f64` bit for bit, with
//! `times.npy`, the `.pvd` collection and the `.vtp` meshes; rejected input writes nothing.

use std::path::{Path, PathBuf};

use mobo::io::frames::{CellFrame, FrameFormats, FrameWriter};
use mobo::io::{npy, IoError};
use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::{shapes, Surface};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mobo_io_frames_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

struct Cell {
    surface: Surface,
    positions: Vec<f64>,
    tension: Vec<f64>,
}

/// Two spheres 5 apart, with tensions that differ per cell and frame (and some awkward bits).
fn cells(p: usize, frame: usize) -> Vec<Cell> {
    let sht = ShTransform::new(p).unwrap();
    let np = sht.n_points();
    (0..2)
        .map(|c| {
            let mut surface = shapes::sphere(p, 1.0 + 0.25 * c as f64).unwrap();
            surface.translate([5.0 * c as f64, 0.1 * frame as f64, 0.0]);
            let positions = surface.grid_positions(&sht).unwrap();
            let mut tension: Vec<f64> = (0..np)
                .map(|j| (j as f64 + 0.1).sin() * (1 + c + 10 * frame) as f64)
                .collect();
            tension[0] = -0.0;
            tension[1] = f64::MIN_POSITIVE / 8.0;
            Cell {
                surface,
                positions,
                tension,
            }
        })
        .collect()
}

fn frames_of(cs: &[Cell], p: usize) -> Vec<CellFrame<'_>> {
    cs.iter()
        .map(|c| CellFrame {
            order: p,
            coefs: c.surface.coefs(),
            positions: &c.positions,
            tension: &c.tension,
        })
        .collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn stacked(cs: &[Cell], f: impl Fn(&Cell) -> &[f64]) -> Vec<u64> {
    cs.iter().flat_map(|c| bits(f(c))).collect()
}

fn names(d: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn two_frames_of_two_cells() {
    let p = 6;
    let (nc, np) = ((p + 1) * (p + 1) - 1, 2 * p * (p + 1));
    let d = tmpdir("two");
    let mut w = FrameWriter::new(
        &d,
        FrameFormats {
            npy: true,
            hdf5: false,
            vtp: Some(1),
        },
    )
    .unwrap();
    let times = [0.0, 0.125 + 1e-17];
    let all: Vec<Vec<Cell>> = (0..2).map(|f| cells(p, f)).collect();
    for (f, cs) in all.iter().enumerate() {
        w.write_frame(f, times[f], &frames_of(cs, p)).unwrap();
        assert_eq!(w.times(), &times[..=f]);
        // After each frame the indexes list exactly the frames written so far.
        let (shape, t) = npy::read_f64(&d.join("frames/times.npy")).unwrap();
        assert_eq!(shape, vec![f + 1]);
        assert_eq!(bits(&t), bits(&times[..=f]));
    }
    w.finish().unwrap();

    for (f, cs) in all.iter().enumerate() {
        let file = |what: &str| d.join(format!("frames/frame_{f:05}_{what}.npy"));
        let (shape, data) = npy::read_f64(&file("coefs")).unwrap();
        assert_eq!(shape, vec![2, 3, nc]);
        assert_eq!(bits(&data), stacked(cs, |c| c.surface.coefs()));
        let (shape, data) = npy::read_f64(&file("positions")).unwrap();
        assert_eq!(shape, vec![2, 3, np]);
        assert_eq!(bits(&data), stacked(cs, |c| &c.positions));
        // Cell 1's x grid coordinates are its own (5 apart from cell 0's).
        let x0 = data[0];
        let x1 = data[3 * np];
        assert!((x1 - x0 - 5.0).abs() < 0.3, "{x0} {x1}");
        let (shape, data) = npy::read_f64(&file("tension")).unwrap();
        assert_eq!(shape, vec![2, np]);
        assert_eq!(bits(&data), stacked(cs, |c| &c.tension));
    }
    assert_eq!(
        names(&d.join("frames")),
        vec![
            "frame_00000_coefs.npy",
            "frame_00000_positions.npy",
            "frame_00000_tension.npy",
            "frame_00001_coefs.npy",
            "frame_00001_positions.npy",
            "frame_00001_tension.npy",
            "times.npy",
        ]
    );
    assert_eq!(
        names(&d.join("vtk")),
        vec!["frame_00000.vtp", "frame_00001.vtp", "frames.pvd"]
    );

    // The collection lists both frames with their times.
    let pvd = std::fs::read_to_string(d.join("vtk/frames.pvd")).unwrap();
    let sets: Vec<&str> = pvd.split("<DataSet ").skip(1).collect();
    assert_eq!(sets.len(), 2);
    for (f, s) in sets.iter().enumerate() {
        let get = |k: &str| {
            let at = s.find(&format!("{k}=\"")).unwrap() + k.len() + 2;
            s[at..at + s[at..].find('"').unwrap()].to_string()
        };
        assert_eq!(get("file"), format!("frame_{f:05}.vtp"));
        assert_eq!(
            get("timestep").parse::<f64>().unwrap().to_bits(),
            times[f].to_bits()
        );
    }

    // Each .vtp holds two meshes of 42 vertices / 80 triangles (one subdivision), cell 0 near
    // the origin and cell 1 near x = 5.
    for f in 0..2 {
        let vtp = std::fs::read_to_string(d.join(format!("vtk/frame_{f:05}.vtp"))).unwrap();
        assert!(vtp.contains("NumberOfPoints=\"84\""));
        assert!(vtp.contains("NumberOfPolys=\"160\""));
        let pd = &vtp[vtp.find("<PointData").unwrap()..vtp.find("</PointData>").unwrap()];
        let at = pd.find("Name=\"cell\"").unwrap();
        let body = &pd[at + pd[at..].find('>').unwrap() + 1..];
        let ids: Vec<i32> = body[..body.find("</DataArray>").unwrap()]
            .split_whitespace()
            .map(|w| w.parse().unwrap())
            .collect();
        assert_eq!(ids.len(), 84);
        assert!(ids[..42].iter().all(|&c| c == 0) && ids[42..].iter().all(|&c| c == 1));
    }
    // No temporary files anywhere.
    for sub in ["frames", "vtk"] {
        assert!(names(&d.join(sub)).iter().all(|n| !n.starts_with('.')));
    }
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn bad_frames_are_errors_that_write_nothing() {
    let p = 4;
    let d = tmpdir("bad");
    let fmt = FrameFormats {
        npy: true,
        hdf5: false,
        vtp: Some(0),
    };
    let mut w = FrameWriter::new(&d, fmt).unwrap();
    let cs = cells(p, 0);
    let mut fr = frames_of(&cs, p);
    let check = |r: Result<(), IoError>, words: &[&str]| {
        let e = r.unwrap_err();
        assert!(matches!(e, IoError::Frame { .. }), "{e:?}");
        let m = e.to_string();
        for w in words {
            assert!(m.contains(w), "'{m}' lacks '{w}'");
        }
    };
    check(w.write_frame(0, 0.0, &[]), &["at least one cell"]);
    check(w.write_frame(1, 0.0, &fr), &["frame 1", "numbered"]);
    let short = &cs[1].tension[1..];
    fr[1].tension = short;
    check(
        w.write_frame(0, 0.0, &fr),
        &["cell 1", "tension", "needs 40"],
    );
    fr[1].tension = &cs[1].tension;
    fr[1].order = 5;
    check(w.write_frame(0, 0.0, &fr), &["cell 1", "order 5"]);
    fr[1].order = p;
    assert!(names(&d.join("frames")).is_empty());
    assert!(names(&d.join("vtk")).is_empty());
    w.write_frame(0, 0.0, &fr).unwrap();
    // The mesh order is fixed by the first frame.
    let cs6 = cells(6, 1);
    check(w.write_frame(1, 1.0, &frames_of(&cs6, 6)), &["order 6"]);
    assert_eq!(w.times(), &[0.0]);
    w.finish().unwrap();
    let e = FrameWriter::new(
        &d,
        FrameFormats {
            vtp: Some(11),
            ..fmt
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("subdivisions"), "{e}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[cfg(not(feature = "hdf5"))]
#[test]
fn hdf5_without_the_feature_is_a_clear_error() {
    let d = tmpdir("noh5");
    std::fs::create_dir_all(d.join("frames")).unwrap();
    let old = d.join("frames/frame_00000_coefs.npy");
    std::fs::write(&old, b"an earlier run's frame").unwrap();
    let e = FrameWriter::new(
        &d,
        FrameFormats {
            npy: true,
            hdf5: true,
            vtp: None,
        },
    )
    .unwrap_err();
    assert!(matches!(e, IoError::Hdf5Unavailable { .. }));
    assert!(
        e.to_string().contains("built without the hdf5 feature"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn resume_keeps_the_frames_before_the_checkpoint() {
    let p = 3;
    let d = tmpdir("resume");
    let fmt = FrameFormats {
        npy: true,
        hdf5: false,
        vtp: Some(0),
    };
    let mut w = FrameWriter::new(&d, fmt).unwrap();
    let all: Vec<Vec<Cell>> = (0..4).map(|f| cells(p, f)).collect();
    for (f, cs) in all.iter().enumerate().take(3) {
        w.write_frame(f, f as f64, &frames_of(cs, p)).unwrap();
    }
    drop(w); // the run dies after frame 2; its checkpoint was taken after frame 1

    // Resuming after more frames than exist is refused before anything is touched.
    let e = FrameWriter::resume(&d, fmt, &[0.0, 1.0, 2.0, 3.0]).unwrap_err();
    assert!(
        e.to_string().contains("frame_00003_coefs.npy is missing"),
        "{e}"
    );
    assert!(d.join("frames/frame_00002_coefs.npy").exists());

    let mut w = FrameWriter::resume(&d, fmt, &[0.0, 1.0]).unwrap();
    assert!(!d.join("frames/frame_00002_coefs.npy").exists());
    assert!(!d.join("vtk/frame_00002.vtp").exists());
    let (_, t) = npy::read_f64(&d.join("frames/times.npy")).unwrap();
    assert_eq!(t, vec![0.0, 1.0]);
    let pvd = std::fs::read_to_string(d.join("vtk/frames.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet ").count(), 2);
    // Frame 1's files are untouched; the new frame 2 holds the new data.
    let (_, c1) = npy::read_f64(&d.join("frames/frame_00001_coefs.npy")).unwrap();
    assert_eq!(bits(&c1), stacked(&all[1], |c| c.surface.coefs()));
    w.write_frame(2, 2.5, &frames_of(&all[3], p)).unwrap();
    w.finish().unwrap();
    let (_, c2) = npy::read_f64(&d.join("frames/frame_00002_coefs.npy")).unwrap();
    assert_eq!(bits(&c2), stacked(&all[3], |c| c.surface.coefs()));
    let (_, t) = npy::read_f64(&d.join("frames/times.npy")).unwrap();
    assert_eq!(t, vec![0.0, 1.0, 2.5]);

    // A new run in the same directory starts from nothing.
    let mut w = FrameWriter::new(&d, fmt).unwrap();
    assert!(names(&d.join("frames")).is_empty());
    assert!(names(&d.join("vtk")).is_empty());
    w.write_frame(0, 7.0, &frames_of(&all[0], p)).unwrap();
    assert_eq!(names(&d.join("vtk")), vec!["frame_00000.vtp", "frames.pvd"]);
    std::fs::remove_dir_all(&d).unwrap();
}
