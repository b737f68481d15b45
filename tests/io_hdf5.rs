//! `frames.h5`: three frames of two cells written by the FrameWriter and read back with the
//! `hdf5` crate (not mobo's code), compared bit for bit; the file grows as
//! `frames.h5.partial` and becomes `frames.h5` on `finish`.
#![cfg(feature = "hdf5")]

use mobo::io::frames::{CellFrame, FrameFormats, FrameWriter};
use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::shapes;

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Frame `f` of two cells of order `p`: `(coefs, positions, tension)` per cell.
type Arrays = (Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>);

fn arrays(p: usize, f: usize) -> Arrays {
    let sht = ShTransform::new(p).unwrap();
    let np = sht.n_points();
    let mut out: Arrays = Default::default();
    for c in 0..2 {
        let mut s = shapes::ellipsoid(p, [1.0 + 0.1 * f as f64, 0.9, 0.8]).unwrap();
        s.translate([4.0 * c as f64, 0.0, 0.0]);
        out.0.push(s.coefs().to_vec());
        out.1.push(s.grid_positions(&sht).unwrap());
        out.2
            .push((0..np).map(|j| ((j * (c + 1 + f)) as f64).cos()).collect());
    }
    out
}

fn cells_of(p: usize, a: &Arrays) -> Vec<CellFrame<'_>> {
    (0..2)
        .map(|c| CellFrame {
            order: p,
            coefs: &a.0[c],
            positions: &a.1[c],
            tension: &a.2[c],
        })
        .collect()
}

fn frame_names(path: &std::path::Path) -> Vec<String> {
    let file = hdf5::File::open(path).unwrap();
    let mut g = file.member_names().unwrap();
    g.sort();
    g
}

fn read_tension(path: &std::path::Path, f: usize) -> Vec<f64> {
    let file = hdf5::File::open(path).unwrap();
    file.dataset(&format!("frame_{f:05}/tension"))
        .unwrap()
        .read_raw()
        .unwrap()
}

#[test]
fn resume_after_a_crash_and_after_a_finished_run() {
    let p = 3;
    let d = std::env::temp_dir().join(format!("mobo_io_h5_resume_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let fmt = FrameFormats {
        npy: false,
        hdf5: true,
        vtp: None,
    };
    let frames: Vec<Arrays> = (0..5).map(|f| arrays(p, f)).collect();
    let mut w = FrameWriter::new(&d, fmt).unwrap();
    for (f, a) in frames.iter().enumerate().take(3) {
        w.write_frame(f, f as f64, &cells_of(p, a)).unwrap();
    }
    drop(w); // crash: the flushed partial file holds the three frames
    let partial = d.join("frames.h5.partial");
    assert_eq!(
        frame_names(&partial),
        vec!["frame_00000", "frame_00001", "frame_00002"]
    );
    // Resume from the checkpoint after frame 1: frame 2 is dropped and rewritten.
    let mut w = FrameWriter::resume(&d, fmt, &[0.0, 1.0]).unwrap();
    w.write_frame(2, 2.0, &cells_of(p, &frames[3])).unwrap();
    w.finish().unwrap();
    let h5 = d.join("frames.h5");
    assert_eq!(
        frame_names(&h5),
        vec!["frame_00000", "frame_00001", "frame_00002"]
    );
    assert_eq!(bits(&read_tension(&h5, 1)), bits(&frames[1].2.concat()));
    assert_eq!(bits(&read_tension(&h5, 2)), bits(&frames[3].2.concat()));
    // Resume a finished run and extend it.
    let mut w = FrameWriter::resume(&d, fmt, &[0.0, 1.0, 2.0]).unwrap();
    assert!(partial.exists() && !h5.exists());
    w.write_frame(3, 3.0, &cells_of(p, &frames[4])).unwrap();
    w.finish().unwrap();
    assert_eq!(frame_names(&h5).len(), 4);
    assert_eq!(bits(&read_tension(&h5, 3)), bits(&frames[4].2.concat()));
    // Missing frames are an error naming the group.
    let e = FrameWriter::resume(&d, fmt, &[0.0; 6])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frame_00004 is missing") && e.contains("frames.h5"),
        "{e}"
    );
    assert!(
        h5.exists() && !partial.exists(),
        "a refused resume changes nothing"
    );
    // A new run removes the old file.
    let w = FrameWriter::new(&d, fmt).unwrap();
    assert!(!h5.exists());
    w.finish().unwrap();
    assert!(frame_names(&h5).is_empty());
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn three_frames_of_two_cells_round_trip() {
    let p = 5;
    let sht = ShTransform::new(p).unwrap();
    let (nc, np) = (sht.n_coefs(), sht.n_points());
    let d = std::env::temp_dir().join(format!("mobo_io_h5_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let mut w = FrameWriter::new(
        &d,
        FrameFormats {
            npy: false,
            hdf5: true,
            vtp: None,
        },
    )
    .unwrap();
    let times = [0.0, 0.5, 1.0 + 1e-15];
    let mut expected = Vec::new();
    for (f, &t) in times.iter().enumerate() {
        let mut coefs = Vec::new();
        let mut pos = Vec::new();
        let mut ten = Vec::new();
        for c in 0..2 {
            let mut s = shapes::ellipsoid(p, [1.0 + 0.1 * f as f64, 0.9, 0.8]).unwrap();
            s.translate([4.0 * c as f64, 0.0, 0.0]);
            coefs.push(s.coefs().to_vec());
            pos.push(s.grid_positions(&sht).unwrap());
            let mut tension: Vec<f64> = (0..np).map(|j| ((j * (c + 1)) as f64).cos()).collect();
            tension[3] = -0.0;
            tension[4] = f64::from_bits(7); // subnormal
            ten.push(tension);
        }
        let cells: Vec<CellFrame> = (0..2)
            .map(|c| CellFrame {
                order: p,
                coefs: &coefs[c],
                positions: &pos[c],
                tension: &ten[c],
            })
            .collect();
        w.write_frame(f, t, &cells).unwrap();
        // Frames are flushed as they are written; the final name appears only on finish.
        assert!(d.join("frames.h5.partial").exists());
        assert!(!d.join("frames.h5").exists());
        expected.push((coefs.concat(), pos.concat(), ten.concat()));
    }
    w.finish().unwrap();
    assert!(!d.join("frames.h5.partial").exists());

    let file = hdf5::File::open(d.join("frames.h5")).unwrap();
    let mut groups = file.member_names().unwrap();
    groups.sort();
    assert_eq!(groups, vec!["frame_00000", "frame_00001", "frame_00002"]);
    for (f, (coefs, pos, ten)) in expected.iter().enumerate() {
        let g = file.group(&format!("frame_{f:05}")).unwrap();
        let t: f64 = g.attr("time").unwrap().read_scalar().unwrap();
        assert_eq!(t.to_bits(), times[f].to_bits());
        let order: u64 = g.attr("order").unwrap().read_scalar().unwrap();
        assert_eq!(order, p as u64);
        for (name, shape, want) in [
            ("coefs", vec![2, 3, nc], coefs),
            ("positions", vec![2, 3, np], pos),
            ("tension", vec![2, np], ten),
        ] {
            let ds = g.dataset(name).unwrap();
            assert_eq!(ds.shape(), shape, "{name}");
            let got: Vec<f64> = ds.read_raw().unwrap();
            assert_eq!(bits(&got), bits(want), "frame {f} {name}");
        }
    }
    drop(file);
    std::fs::remove_dir_all(&d).unwrap();
}
