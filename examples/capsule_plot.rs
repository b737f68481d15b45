//! The plot of docs/capsules.md: steady Taylor deformation of a capsule in shear against `Ca`
//! from the output of `scripts/capsule_shear.sh` (neo-Hookean and Skalak `C = 1`), with the
//! published neo-Hookean values (Ramanujan & Pozrikidis 1998) and the small-deformation limit
//! `D = (25/4) Ca` (Barthès-Biesel & Rallison 1981):
//! `cargo run --release --example capsule_plot -- docs/capsule_shear_runs.txt docs/capsule_shear.png`.
use plotters::prelude::*;

/// Published neo-Hookean steady `D` (design 5): `(Ca, D)`.
const PUBLISHED: [(f64, f64); 5] = [
    (0.0125, 0.072),
    (0.025, 0.150),
    (0.05, 0.26),
    (0.1, 0.385),
    (0.2, 0.50),
];

/// `(law, Ca, D)` of the rows `steady D … (law, Ca c, …` of the script's output.
fn rows(text: &str) -> Vec<(String, f64, f64)> {
    text.lines()
        .filter_map(|l| {
            let d: f64 = l
                .strip_prefix("steady D ")?
                .split_whitespace()
                .next()?
                .parse()
                .ok()?;
            let inner = l.split(" (").nth(1)?;
            let mut parts = inner.split(", ");
            let law = parts.next()?.to_string();
            let ca: f64 = parts.next()?.strip_prefix("Ca ")?.parse().ok()?;
            Some((law, ca, d))
        })
        .collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let input = a.first().ok_or("usage: capsule_plot RUNS.txt OUT.png")?;
    let out = a.get(1).ok_or("usage: capsule_plot RUNS.txt OUT.png")?;
    let text = std::fs::read_to_string(input).map_err(|e| format!("{input}: {e}"))?;
    let data = rows(&text);
    if data.is_empty() {
        return Err(format!("{input}: no 'steady D' rows").into());
    }
    mobo::report::plot::ensure_font()?;
    let root = BitMapBackend::new(out, (800, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Capsule in simple shear: steady Taylor deformation",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..0.21, 0.0..0.6)?;
    chart
        .configure_mesh()
        .x_desc("Ca = μγ̇a/E_s (E_s = 3G_s)")
        .y_desc("D = (L − B)/(L + B)")
        .label_style(("sans-serif", 14))
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            [(0.0, 0.0), (0.08, 0.5)],
            BLACK.stroke_width(1),
        ))?
        .label("(25/4) Ca, Barthès-Biesel & Rallison 1981")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
    for (law, name, color) in [
        ("nh", "mobo, neo-Hookean", RGBColor(31, 119, 180)),
        ("sk", "mobo, Skalak C = 1", RGBColor(214, 39, 40)),
    ] {
        let pts: Vec<(f64, f64)> = data
            .iter()
            .filter(|r| r.0 == law)
            .map(|r| (r.1, r.2))
            .collect();
        chart
            .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
        chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))?;
    }
    chart
        .draw_series(
            PUBLISHED
                .iter()
                .map(|&p| Cross::new(p, 6, BLACK.stroke_width(2))),
        )?
        .label("neo-Hookean, Ramanujan & Pozrikidis 1998")
        .legend(|(x, y)| Cross::new((x + 10, y), 6, BLACK.stroke_width(2)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    root.present()?;
    println!("wrote {out}");
    Ok(())
}
