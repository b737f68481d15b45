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
