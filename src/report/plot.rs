//! The report's plots (plotters; PNG and SVG): error against bake time, shading cost, texture
//! memory and, when measured, frame time (one point per configuration, the Pareto front — no other point is both
//! cheaper and more accurate — drawn as a line), and error against MIP level (the best
//! configuration of each level marked).
//!
//! Text needs a TrueType font: DejaVu Sans (Debian `fonts-dejavu-core`) or `NDFMAP_FONT`.
//! Without one the plots are skipped and the report says so.

use super::{Report, Row};
use crate::error::{Error, Result};
use crate::format::Format;
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Registers a font under the name "sans-serif" once; false when none was found.
fn font() -> bool {
    static OK: OnceLock<bool> = OnceLock::new();
    *OK.get_or_init(|| {
        let mut candidates: Vec<std::path::PathBuf> = Vec::new();
        if let Some(p) = std::env::var_os("NDFMAP_FONT") {
            candidates.push(p.into());
        }
        for p in [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
        ] {
            candidates.push(p.into());
        }
        for p in candidates {
            if let Ok(bytes) = std::fs::read(&p) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return true;
                }
            }
        }
        false
    })
}

/// Indices of the Pareto-optimal points (minimal x and y), sorted by x.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].0.is_finite() && points[i].1.is_finite())
        .collect();
    idx.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
    });
    let mut front = Vec::new();
    let mut best = f64::INFINITY;
    for i in idx {
        if points[i].1 < best {
            best = points[i].1;
            front.push(i);
        }
    }
    front
}

/// One labelled point.
struct Point {
    label: String,
    x: f64,
    y: f64,
}

fn plot_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn log_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for v in values.filter(|v| v.is_finite() && *v > 0.0) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.1, 1.0);
    }
    (lo / 1.5, hi * 1.5)
}

/// A tick label: `v` with three significant digits, trailing zeros dropped (`0.0003`, not
/// `0.00030000000000000003`; `12.5`; `1500`).
fn tick_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    let text = format!("{v:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// Draws a log-log scatter with labels and the Pareto front.
fn scatter<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    points: &[Point],
) -> std::result::Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (x0, x1) = log_range(points.iter().map(|p| p.x));
    let (y0, y1) = log_range(points.iter().map(|p| p.y));
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .y_labels(12)
        .x_labels(12)
        .y_label_formatter(&|y| tick_label(*y))
        .x_label_formatter(&|x| tick_label(*x))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| e.to_string())?;
    let xy: Vec<(f64, f64)> = points.iter().map(|p| (p.x, p.y)).collect();
    let front = pareto_front(&xy);
    chart
        .draw_series(LineSeries::new(
            front.iter().map(|&i| xy[i]),
            RED.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED.stroke_width(2)));
    for (i, p) in points.iter().enumerate() {
        if !(p.x > 0.0 && p.y > 0.0 && p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        let on_front = front.contains(&i);
        let colour = if on_front { RED } else { BLUE };
        let style = ("sans-serif", 12).into_font().color(&BLACK);
        chart
            .draw_series(std::iter::once(
                EmptyElement::at((p.x, p.y))
                    + Circle::new((0, 0), 4, colour.filled())
                    + Text::new(p.label.clone(), (6, -6), style),
            ))
            .map_err(|e| e.to_string())?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

/// Draws error against MIP level: one line per configuration, the best of each level marked.
fn levels_chart<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    series: &[(String, Vec<(f64, f64)>)],
) -> std::result::Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let max_level = series
        .iter()
        .flat_map(|s| s.1.iter().map(|p| p.0))
        .fold(1.0f64, f64::max);
    let (y0, y1) = log_range(series.iter().flat_map(|s| s.1.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..max_level + 0.5, (y0..y1).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("MIP level (texel space) / centre λ (image space)")
        .y_desc("relative RMS error")
        .y_labels(12)
        .y_label_formatter(&|y| tick_label(*y))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| e.to_string())?;
    for (k, (label, pts)) in series.iter().enumerate() {
        let colour = Palette99::pick(k).to_rgba();
        chart
            .draw_series(LineSeries::new(
                pts.iter().copied().filter(|p| p.1 > 0.0 && p.1.is_finite()),
                colour.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label(label.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
            });
    }
    // The best configuration at each level (the lower envelope: the per-level Pareto choice).
    let mut best: Vec<(f64, f64)> = Vec::new();
    for (_, pts) in series {
        for &(x, y) in pts {
            if !(y > 0.0 && y.is_finite()) {
                continue;
            }
            match best.iter_mut().find(|b| b.0 == x) {
                Some(b) if y < b.1 => b.1 = y,
                Some(_) => {}
                None => best.push((x, y)),
            }
        }
    }
    chart
        .draw_series(
            best.iter()
                .map(|&p| Cross::new(p, 6, BLACK.stroke_width(2))),
        )
        .map_err(|e| e.to_string())?
        .label("best at the level")
        .legend(|(x, y)| Cross::new((x + 9, y), 5, BLACK.stroke_width(2)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

const W: u32 = 1000;
const H: u32 = 700;

/// Renders one chart to `stem.png` and `stem.svg` in `out`; returns the file names.
fn both(
    out: &Path,
    stem: &str,
    draw_png: impl Fn(
        DrawingArea<BitMapBackend, plotters::coord::Shift>,
    ) -> std::result::Result<(), String>,
    draw_svg: impl Fn(
        DrawingArea<SVGBackend, plotters::coord::Shift>,
    ) -> std::result::Result<(), String>,
) -> Result<Vec<String>> {
    let png = out.join(format!("{stem}.png"));
    let svg = out.join(format!("{stem}.svg"));
    let mut buf = vec![255u8; (W * H * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (W, H)).into_drawing_area();
        draw_png(root).map_err(|e| plot_err(&png, e))?;
    }
    super::save_rgb(&png, W, H, buf)?;
    {
        let root = SVGBackend::new(&svg, (W, H)).into_drawing_area();
        draw_svg(root).map_err(|e| plot_err(&svg, e))?;
    }
    Ok(vec![format!("{stem}.png"), format!("{stem}.svg")])
}

/// Mean of `f` over the maps for each configuration and format (rows of every map present).
fn aggregate(
    report: &Report,
    format: Format,
    f: impl Fn(&Row) -> Option<f64>,
) -> Vec<(String, f64, &Row)> {
    let mut out: Vec<(String, f64, &Row)> = Vec::new();
    let first_map = report
        .maps
        .first()
        .map(|m| m.name.clone())
        .unwrap_or_default();
    for r in report
        .rows
        .iter()
        .filter(|r| r.format == format && r.map == first_map)
    {
        let vals: Vec<f64> = report
            .rows
            .iter()
            .filter(|o| o.config == r.config && o.format == format)
            .filter_map(&f)
            .collect();
        if !vals.is_empty() {
            out.push((
                r.config.clone(),
                vals.iter().sum::<f64>() / vals.len() as f64,
                r,
            ));
        }
    }
    out
}

/// The error a plot uses for a row: the image-space mean when rendered, else texel space.
fn row_error(r: &Row) -> Option<f64> {
    r.image_rmse().or(Some(r.texel_specular))
}

/// Writes every plot into `out` (averaged over the report's maps); returns the file names, or
/// an empty list when no font is available.
pub fn write_plots(report: &Report, out: &Path) -> Result<Vec<String>> {
    if !font() || report.rows.is_empty() {
        return Ok(Vec::new());
    }
    let measure = if report.rows.iter().any(|r| !r.views.is_empty()) {
        "image-space relative RMSE (mean over views and maps)"
    } else {
        "texel-space relative RMS error"
    };
    let mut files = Vec::new();
    let errors = aggregate(report, Format::F32, row_error);
    let with = |x: &dyn Fn(&Row) -> Option<f64>| -> Vec<Point> {
        errors
            .iter()
            .filter_map(|(label, e, r)| {
                let xs: Vec<f64> = report
                    .rows
                    .iter()
                    .filter(|o| o.config == r.config && o.format == r.format)
                    .filter_map(x)
                    .collect();
                (!xs.is_empty()).then(|| Point {
                    label: label.clone(),
                    x: xs.iter().sum::<f64>() / xs.len() as f64,
                    y: *e,
                })
            })
            .collect()
    };
    let charts: [(&str, &str, &str, Vec<Point>); 3] = [
        (
            "error_vs_bake_time",
            "Error against bake time",
            "bake seconds (mean over maps)",
            with(&|r| Some(r.bake_seconds)),
        ),
        (
            "error_vs_shading_cost",
            "Error against shading cost",
            "ALU instructions per pixel (SPIR-V, loops weighted)",
            with(&|r| r.cost.alu.map(|a| a as f64)),
        ),
        (
            "error_vs_texture_memory",
            "Error against texture memory",
            "texture MiB (all levels)",
            {
                // f32 and every rendered narrower format: formats trade memory for error.
                let mut pts = Vec::new();
                for &format in &report.options.image_formats {
                    let errs = aggregate(report, format, row_error);
                    for (label, e, r) in errs {
                        pts.push(Point {
                            label: if format == Format::F32 {
                                label
                            } else {
                                format!("{label} {format}")
                            },
                            x: r.texture_bytes as f64 / 1048576.0,
                            y: e,
                        });
                    }
                }
                pts
            },
        ),
    ];
    for (stem, title, x_desc, points) in &charts {
        files.extend(both(
            out,
            stem,
            |root| scatter(root, title, x_desc, measure, points),
            |root| scatter(root, title, x_desc, measure, points),
        )?);
    }
    // Frame time, as the ratio to plain's: on a software rasterizer only the ratio means much.
    let frame_points = with(&|r| r.frame_ratio);
    if !frame_points.is_empty() {
        let (title, x_desc) = (
            "Error against frame time",
            "frame time / plain's (viewer benchmark, mean over its views)",
        );
        files.extend(both(
            out,
            "error_vs_frame_time",
            |root| scatter(root, title, x_desc, measure, &frame_points),
            |root| scatter(root, title, x_desc, measure, &frame_points),
        )?);
    }
    // Error against MIP level: texel space per level, image space per zoom view's centre λ.
    let show = [
        "plain",
        "toksvig",
        "lean",
        "olano",
        "tan2005-4",
        "vmf6",
        "vmf6a",
        "vmf8",
    ];
    let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for (label, _, r) in aggregate(report, Format::F32, |r| Some(r.texel_specular)) {
        if !show.contains(&label.as_str()) {
            continue;
        }
        let levels = r.texel_levels.len();
        let pts: Vec<(f64, f64)> = (1..levels)
            .map(|k| {
                let vals: Vec<f64> = report
                    .rows
                    .iter()
                    .filter(|o| o.config == r.config && o.format == Format::F32)
                    .filter_map(|o| o.texel_levels.get(k).copied())
                    .collect();
                (
                    k as f64,
                    vals.iter().sum::<f64>() / vals.len().max(1) as f64,
                )
            })
            .collect();
        series.push((format!("{label} (texel)"), pts));
    }
    files.extend(both(
        out,
        "error_vs_mip_level",
        |root| {
            levels_chart(
                root,
                "Texel-space specular error against MIP level",
                &series,
            )
        },
        |root| {
            levels_chart(
                root,
                "Texel-space specular error against MIP level",
                &series,
            )
        },
    )?);
    let mut image_series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    if let Some(first) = report.maps.first() {
        for (label, _, r) in aggregate(report, Format::F32, |r| r.image_rmse()) {
            if !show.contains(&label.as_str()) {
                continue;
            }
            let pts: Vec<(f64, f64)> = first
                .views
                .iter()
                .filter(|v| v.scene.name.starts_with("zoom"))
                .map(|v| {
                    let vals: Vec<f64> = report
                        .rows
                        .iter()
                        .filter(|o| o.config == r.config && o.format == Format::F32)
                        .filter_map(|o| o.views.iter().find(|e| e.view == v.scene.name))
                        .map(|e| e.rel_rmse)
                        .collect();
                    (
                        v.median_lod.max(0.0),
                        vals.iter().sum::<f64>() / vals.len().max(1) as f64,
                    )
                })
                .collect();
            image_series.push((format!("{label} (image)"), pts));
        }
    }
    if !image_series.is_empty() {
        files.extend(both(
            out,
            "image_error_vs_lod",
            |root| {
                levels_chart(
                    root,
                    "Image-space error along the zoom sequence",
                    &image_series,
                )
            },
            |root| {
                levels_chart(
                    root,
                    "Image-space error along the zoom sequence",
                    &image_series,
                )
            },
        )?);
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 13: a log axis tick at 3e-4 read `0.00030000000000000003`.
    #[test]
    fn tick_labels_have_three_significant_digits_at_most() {
        assert_eq!(tick_label(0.1 * 0.003), "0.0003");
        assert_eq!(tick_label(0.00030000000000000003), "0.0003");
        assert_eq!(tick_label(12.5), "12.5");
        assert_eq!(tick_label(1500.0), "1500");
        assert_eq!(tick_label(0.123456), "0.123");
        assert_eq!(tick_label(1.0), "1");
        assert_eq!(tick_label(0.0), "0");
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let pts = [
            (1.0, 5.0),
            (2.0, 3.0),
            (3.0, 4.0),
            (4.0, 1.0),
            (0.5, 9.0),
            (5.0, 1.0),
        ];
        // (3,4) is dominated by (2,3); (5,1) by (4,1).
        assert_eq!(pareto_front(&pts), vec![4, 0, 1, 3]);
        assert!(pareto_front(&[(f64::NAN, 1.0)]).is_empty());
    }
}
