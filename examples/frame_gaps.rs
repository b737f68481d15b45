//! An independent check of the contact guarantee on a run's frames: the least gap between the
//! cells of every `frames/frame_*_coefs.npy`, and from spherical walls centred at the origin,
//! measured on a finer grid than the contact projection uses.
//!
//! Each cell is sampled on the grid of order `FINE` (8 320 points at 64), and every sample's
//! signed distance to each neighbour is Newton's closest point on the neighbour's continuous
//! surface; a sphere wall's distance is exact (`R − |x|` inside a container of radius `R`,
//! `|x| − r` outside a body of radius `r`). The projection measures from order-`2p` samples plus
//! Newton searches from the minima of their gaps along the grid lines, so this checks what it
//! guarantees with denser samples and no shared code path but the closest-point solve.
//!
//! `cargo run --release --example frame_gaps -- OUT/frames [--container R] [--body r]`
//! prints one line per frame (the least cell–cell and cell–wall gaps, and where) and the least
//! over all frames.
use std::path::Path;

use mobo::linalg3::dist3;
use mobo::sph_harmonics::{CoefLayout, ShTransform};
use mobo::vesicle::surface_distance::{DistanceScratch, SurfaceDistance};

/// The order of the grid the cells are sampled on.
const FINE: usize = 64;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: frame_gaps FRAMES_DIR [--container R] [--body r]";
    let dir = Path::new(args.first().ok_or(usage)?);
    let value = |key: &str| -> Result<Option<f64>, Box<dyn std::error::Error>> {
        match args.iter().position(|a| a == key) {
            None => Ok(None),
            Some(i) => Ok(Some(args.get(i + 1).ok_or(usage)?.parse()?)),
        }
    };
    let (container, body) = (value("--container")?, value("--body")?);
    let mut frames: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("frame_") && n.ends_with("_coefs.npy"))
        })
        .collect();
    frames.sort();
    let mut worst = (f64::INFINITY, f64::INFINITY);
    for path in &frames {
        let (shape, data) = mobo::io::npy::read_f64(path)?;
        let [n, 3, ncoef] = shape[..] else {
            return Err(format!(
                "{}: shape {shape:?}, not (cells, 3, coefficients)",
                path.display()
            )
            .into());
        };
        let p = (1..=64)
            .find(|&p| CoefLayout::new(p).len() == ncoef)
            .ok_or_else(|| format!("{}: {ncoef} coefficients is no order", path.display()))?;
        let cells: Vec<&[f64]> = data.chunks(3 * ncoef).collect();
        let coarse_sht = ShTransform::new(2 * p)?;
        let fine_sht = ShTransform::new(FINE)?;
        let coarse: Vec<SurfaceDistance> = cells
            .iter()
            .map(|c| SurfaceDistance::new(p, c, &coarse_sht))
            .collect::<Result<_, _>>()?;
        let fine: Vec<SurfaceDistance> = cells
            .iter()
            .map(|c| SurfaceDistance::new(p, c, &fine_sht))
            .collect::<Result<_, _>>()?;
        let mut scratch = DistanceScratch::new(p);
        let (mut pair, mut pair_at) = (f64::INFINITY, (0, 0));
        for (a, fa) in fine.iter().enumerate() {
            for (b, cb) in coarse.iter().enumerate() {
                let far = dist3(fa.centre(), cb.centre()) > fa.reach() + cb.reach() + 0.5;
                if a == b || far {
                    continue;
                }
                for &x in fa.samples() {
                    if let Some(cl) = cb.closest_within(&mut scratch, x, 0.5) {
                        if cl.distance < pair {
                            (pair, pair_at) = (cl.distance, (a, b));
                        }
                    }
                }
            }
        }
        let (mut wall, mut wall_at) = (f64::INFINITY, 0);
        for (a, f) in fine.iter().enumerate() {
            for &x in f.samples() {
                let r = dist3(x, [0.0; 3]);
                let g = container
                    .map_or(f64::INFINITY, |big| big - r)
                    .min(body.map_or(f64::INFINITY, |small| r - small));
                if g < wall {
                    (wall, wall_at) = (g, a);
                }
            }
        }
        // The same pair by brute force: the least distance between the two fine point sets
        // (unsigned: where the surfaces cross it is within the fine spacing of zero).
        let (a, b) = pair_at;
        let cloud = fine[a]
            .samples()
            .iter()
            .flat_map(|&x| fine[b].samples().iter().map(move |&y| dist3(x, y)))
            .fold(f64::INFINITY, f64::min);
        println!(
            "{}: {n} cells, least gap between cells {pair:.6e} (cells {a} and {b}; their fine \
             point sets {cloud:.6e} apart), from the walls {wall:.6e} (cell {wall_at})",
            path.file_name().and_then(|s| s.to_str()).unwrap_or("?"),
        );
        worst = (worst.0.min(pair), worst.1.min(wall));
    }
    println!(
        "{} frames: least gap between cells {:.6e}, from the walls {:.6e}",
        frames.len(),
        worst.0,
        worst.1
    );
    Ok(())
}
