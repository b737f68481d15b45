//! PNG plot of the accuracy study: surface distance (Hausdorff, over the radius) against wall time per step, log–log, one curve
//! per knob (the reference, at zero error, cannot be drawn on log axes), the Pareto front of all runs as a dashed black
//! staircase with circled points.
//!
//! Drawn with `plotters` (bitmap backend, no system libraries). Text needs a TrueType font,
//! loaded at run time from `MOBO_FONT` or the usual Debian paths (`fonts-dejavu-core`,
//! `fonts-liberation`); without one the plot is refused with an error that says so.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::prelude::*;
use plotters::style::FontStyle;

use super::study::{Knob, Study};
use super::ReportError;

/// Font files tried in order after `MOBO_FONT`.
const FONT_PATHS: [&str; 4] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
];

static FONT: OnceLock<Result<(), String>> = OnceLock::new();

/// Register a TrueType font as plotters' `sans-serif` (once per process).
pub fn ensure_font() -> Result<(), ReportError> {
    FONT.get_or_init(|| {
        let mut tried = Vec::new();
        let env = std::env::var_os("MOBO_FONT").map(PathBuf::from);
        for path in env.into_iter().chain(FONT_PATHS.iter().map(PathBuf::from)) {
            if let Ok(bytes) = std::fs::read(&path) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return Ok(());
                }
                tried.push(format!("{} (not a usable font)", path.display()));
            } else {
                tried.push(path.display().to_string());
            }
        }
        Err(tried.join(", "))
    })
    .clone()
    .map_err(|tried| ReportError::Font { tried })
}

fn knob_color(k: Knob) -> RGBColor {
    match k {
        Knob::Order => RGBColor(31, 119, 180),
        Knob::Upsample => RGBColor(255, 127, 14),
        Knob::FmmDigits => RGBColor(44, 160, 44),
        Knob::GmresTol => RGBColor(214, 39, 40),
        Knob::DtEuler => RGBColor(148, 103, 189),
        Knob::DtBdf2 => RGBColor(140, 86, 75),
        Knob::Coupling => RGBColor(227, 119, 194),
        Knob::ContactDistance => RGBColor(23, 190, 207),
    }
}

/// Smallest error drawn: exact zeros (a knob with no effect) are drawn at this floor.
const ERROR_FLOOR: f64 = 1e-16;

/// Draw the plot of `study` into `path` (PNG, written atomically).
pub fn error_vs_time(study: &Study, path: &Path) -> Result<(), ReportError> {
    ensure_font()?;
    let err = |m: String| ReportError::Plot {
        path: path.to_path_buf(),
        message: m,
    };
    let pts: Vec<(Knob, f64, f64, bool)> = study
        .rows
        .iter()
        .filter(|r| r.failure.is_none() && r.step_s.is_finite() && r.surface_error.is_finite())
        .map(|r| {
            (
                r.knob.expect("rows have knobs"),
                r.step_s,
                r.surface_error.max(ERROR_FLOOR),
                r.pareto,
            )
        })
        .collect();
    if pts.is_empty() {
        return Err(err("no successful run to plot".into()));
    }
    let (w, h) = (960u32, 640u32);
    // Drawn into a temporary file beside the target, then renamed (atomic, as write_atomic).
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "plot".into());
    let tmp = path.with_file_name(format!(".{name}.tmp.png"));
    {
        let root = BitMapBackend::new(&tmp, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
        let (tmin, tmax) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
        let (emin, emax) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
            (a.min(p.2), b.max(p.2))
        });
        let xr = (tmin / 1.5)..(tmax * 1.5);
        let yr = (emin / 5.0)..(emax * 5.0);
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "Surface distance at t = {} against time per step ({}, {} cells)",
                    study.t_end, study.scene_name, study.cells
                ),
                ("sans-serif", 20),
            )
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(80)
            .build_cartesian_2d(xr.log_scale(), yr.log_scale())
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("wall time per step (s)")
            .y_desc("surface distance / cell radius")
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .x_label_formatter(&|v| format!("{v:.2}"))
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let mut knobs: Vec<Knob> = Vec::new();
        for p in &pts {
            if !knobs.contains(&p.0) {
                knobs.push(p.0);
            }
        }
        for k in knobs {
            let c = knob_color(k);
            let mut series: Vec<(f64, f64)> = study
                .rows
                .iter()
                .filter(|r| r.knob == Some(k) && r.failure.is_none() && r.surface_error.is_finite())
                .map(|r| (r.value, r.step_s, r.surface_error.max(ERROR_FLOOR)))
                .map(|(_, t, e)| (t, e))
                .collect();
            // Join in order of accuracy (error descending) so that each curve reads as the knob
            // is tightened.
            series.sort_by(|a, b| b.1.total_cmp(&a.1));
            chart
                .draw_series(LineSeries::new(series.clone(), c.stroke_width(2)))
                .map_err(|e| err(e.to_string()))?
                .label(k.name())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                });
            chart
                .draw_series(
                    series
                        .iter()
                        .map(|&(t, e)| Circle::new((t, e), 4, c.filled())),
                )
                .map_err(|e| err(e.to_string()))?;
        }
        let mut front: Vec<(f64, f64)> = pts.iter().filter(|p| p.3).map(|p| (p.1, p.2)).collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut stairs = Vec::new();
        for (i, &(t, e)) in front.iter().enumerate() {
            if i > 0 {
                stairs.push((t, front[i - 1].1));
            }
            stairs.push((t, e));
        }
        chart
            .draw_series(DashedLineSeries::new(stairs, 6, 4, BLACK.stroke_width(1)))
            .map_err(|e| err(e.to_string()))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
        chart
            .draw_series(
                front
                    .iter()
                    .map(|&(t, e)| Circle::new((t, e), 8, BLACK.stroke_width(2))),
            )
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| err(e.to_string()))?;
        root.present().map_err(|e| err(e.to_string()))?;
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        err(format!("renaming {}: {e}", tmp.display()))
    })?;
    Ok(())
}
