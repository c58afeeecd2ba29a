//! PNG plots of the results (plotters, bitmap backend, with an embedded DejaVu Sans Mono font so that a
//! machine without fonts draws them too): render time against error with its Pareto front, frames per
//! second against resolution, and planned peak memory against resolution.

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::report::Record;

pub const FILES: [&str; 3] = ["pareto.png", "fps_vs_resolution.png", "memory_vs_resolution.png"];
const SIZE: (u32, u32) = (960, 640);
const FONT: &str = "sans-serif";
const COLORS: [RGBColor; 12] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
    RGBColor(0, 0, 0),
    RGBColor(120, 120, 255),
];

fn font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| register_font(FONT, FontStyle::Normal, include_bytes!("../assets/DejaVuSansMono.ttf")).is_ok());
    if ok {
        Ok(())
    } else {
        Err(anyhow!("the embedded plot font cannot be read"))
    }
}

/// One line (or point set) of a plot: its label, points and, optionally, a tag per point.
struct Series {
    label: String,
    points: Vec<(f64, f64)>,
    tags: Vec<String>,
}

/// Compact axis labels: 3 significant digits with an SI suffix (1.2k, 19.2k, 1.23M) or a short exponent.
fn si(v: &f64) -> String {
    let v = *v;
    let (scaled, suffix) = match v.abs() {
        a if a >= 1e9 => (v / 1e9, "G"),
        a if a >= 1e6 => (v / 1e6, "M"),
        a if a >= 1e3 => (v / 1e3, "k"),
        a if a >= 1.0 || a == 0.0 => (v, ""),
        _ => return format!("{v:.0e}"),
    };
    format!("{}{suffix}", format!("{scaled:.2}").trim_end_matches('0').trim_end_matches('.'))
}

/// Log-log axes spanning every point with a margin.
fn bounds(series: &[Series]) -> Option<((f64, f64), (f64, f64))> {
    let points: Vec<(f64, f64)> =
        series.iter().flat_map(|s| s.points.iter().copied()).filter(|(x, y)| *x > 0.0 && *y > 0.0).collect();
    if points.is_empty() {
        return None;
    }
    let span = |values: Vec<f64>| {
        let (lo, hi) = values.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        (lo / 1.6, hi * 1.6)
    };
    Some((span(points.iter().map(|p| p.0).collect()), span(points.iter().map(|p| p.1).collect())))
}

/// A log-log line plot with markers, written to `path`. `front` is drawn as a thick grey line behind.
fn draw(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    front: Option<&[(f64, f64)]>,
) -> Result<()> {
    font()?;
    let (w, h) = SIZE;
    let mut pixels = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area();
        let err = |e: DrawingAreaErrorKind<_>| anyhow!("drawing {}: {e}", path.display());
        root.fill(&WHITE).map_err(err)?;
        match bounds(series) {
            None => root.draw(&Text::new(format!("{title}: no data"), (20, h as i32 / 2), (FONT, 20))).map_err(err)?,
            Some(((x0, x1), (y0, y1))) => {
                chart(&root, title, x_desc, y_desc, series, front, (x0..x1, y0..y1)).map_err(err)?
            }
        }
        root.present().map_err(err)?;
    }
    save(path, pixels)
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
type DrawResult = std::result::Result<(), DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>>;

fn chart(
    root: &Area,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    front: Option<&[(f64, f64)]>,
    (x, y): (std::ops::Range<f64>, std::ops::Range<f64>),
) -> DrawResult {
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 20))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(80)
        .build_cartesian_2d(x.log_scale(), y.log_scale())?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 14))
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&si)
        .y_label_formatter(&si)
        .draw()?;
    if let Some(front) = front {
        let grey = RGBColor(190, 190, 190).stroke_width(8);
        chart
            .draw_series(LineSeries::new(front.iter().copied(), grey))?
            .label("Pareto front")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey));
    }
    for (i, s) in series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        // Tagged series are point sets (their order means nothing); the others are lines.
        let line = if s.tags.is_empty() { s.points.clone() } else { Vec::new() };
        chart
            .draw_series(LineSeries::new(line, color.stroke_width(2)))?
            .label(s.label.clone())
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
        chart.draw_series(s.points.iter().map(|&p| Circle::new(p, 5, color.filled())))?;
        chart.draw_series(
            s.points
                .iter()
                .zip(&s.tags)
                .map(|(&p, tag)| Text::new(tag.clone(), p, (FONT, 13).into_font().color(&color))),
        )?;
    }
    chart
        .configure_series_labels()
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    Ok(())
}

fn save(path: &Path, pixels: Vec<u8>) -> Result<()> {
    let image = image::RgbImage::from_raw(SIZE.0, SIZE.1, pixels).ok_or_else(|| anyhow!("plot buffer size"))?;
    let mut png = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    crate::report::write_file(path, &png)
}

fn config_label(r: &Record) -> String {
    let decoder = if r.k == 1 { "SRT".to_string() } else { format!("RP k={}", r.k) };
    format!("{} {decoder} {}", r.model, r.precision)
}

/// Series per (model, k, precision) over the sweep records, x and y taken by `point`.
fn by_config(records: &[Record], point: impl Fn(&Record) -> Option<(f64, f64)>) -> Vec<Series> {
    let mut series: Vec<Series> = Vec::new();
    for r in records.iter().filter(|r| r.group == "sweep") {
        let Some(p) = point(r) else { continue };
        let label = config_label(r);
        match series.iter_mut().find(|s| s.label == label) {
            Some(s) => s.points.push(p),
            None => series.push(Series { label, points: vec![p], tags: Vec::new() }),
        }
    }
    series.iter_mut().for_each(|s| s.points.sort_by(|a, b| a.0.total_cmp(&b.0)));
    series
}

/// The points no other point beats in both time and error, by increasing time.
fn pareto_front(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let mut front: Vec<(f64, f64)> = Vec::new();
    for p in sorted {
        if front.last().is_none_or(|last| p.1 < last.1) {
            front.push(p);
        }
    }
    front
}

pub fn draw_all(records: &[Record], out: &Path) -> Result<()> {
    // Render time against error at one target size (the paper's 120×160), over k and precision.
    let size = "120x160";
    let mut pareto: Vec<Series> = Vec::new();
    for r in records.iter().filter(|r| r.group == "sweep" && r.target_size == size) {
        if let (Some(t), Some(e)) = (r.render_ms, r.max_err_f64_reference) {
            let label = format!("{} {}", r.model, r.precision);
            let tag = if r.k == 1 { " SRT".to_string() } else { format!(" k={}", r.k) };
            let p = (t.median_ms, e.max(1e-9));
            match pareto.iter_mut().find(|s| s.label == label) {
                Some(s) => {
                    s.points.push(p);
                    s.tags.push(tag);
                }
                None => pareto.push(Series { label, points: vec![p], tags: vec![tag] }),
            }
        }
    }
    let all: Vec<(f64, f64)> = pareto.iter().flat_map(|s| s.points.iter().copied()).collect();
    draw(
        &out.join(FILES[0]),
        &format!("Render time against error at {size}, over k and precision"),
        "render time (ms)",
        "max |rgb - float64 reference|",
        &pareto,
        Some(&pareto_front(&all)),
    )?;
    draw(
        &out.join(FILES[1]),
        "Frames per second against resolution (1 target view)",
        "pixels per frame",
        "frames per second",
        &by_config(records, |r| r.fps.map(|f| (r.pixels as f64, f))),
        None,
    )?;
    // Beside the engine's planned peaks, what the official SRT and RP-SRT k=16 would hold in softmax scores
    // if they materialised them (the paper's Figure 2a).
    let mut memory = by_config(records, |r| r.render_peak_bytes.map(|b| (r.pixels as f64, b as f64)));
    for k in [1, 16] {
        let scores = by_config(records, |r| {
            (r.model == "official" && r.k == k && r.precision == "f32")
                .then_some((r.pixels as f64, r.attention_scores_bytes as f64))
        });
        memory.extend(
            scores.into_iter().map(|s| Series { label: format!("{} (scores, if materialised)", s.label), ..s }),
        );
    }
    draw(
        &out.join(FILES[2]),
        "Planned peak GPU memory of a render against resolution",
        "pixels per frame",
        "bytes",
        &memory,
        None,
    )
}

#[cfg(test)]
mod tests {
    use super::pareto_front;

    #[test]
    fn the_front_keeps_only_undominated_points() {
        let points = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (0.5, 9.0)];
        assert_eq!(pareto_front(&points), vec![(0.5, 9.0), (1.0, 5.0), (2.0, 3.0), (4.0, 1.0)]);
    }
}
