//! PNG plots of the results (plotters, bitmap backend, with an embedded DejaVu Sans Mono font so that a
//! machine without fonts draws them too): render time against error with its Pareto front, frames per
//! second against resolution, and planned peak memory against resolution.

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::report::Record;

pub const FILES: [&str; 3] = ["pareto.png", "fps_vs_resolution.png", "memory_vs_resolution.png"];
const SIZE: (u32, u32) = (1200, 640);
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

/// One line (or point set) of a plot: its label, points, colour and, optionally, a tag per point.
struct Series {
    label: String,
    points: Vec<(f64, f64)>,
    /// Per-point tags make a point set (no line through the points).
    tags: Vec<String>,
    color: RGBColor,
    dashed: bool,
    /// Points drawn as crosses, without a line (a point set of another kind: PyTorch's beside the engine's).
    cross: bool,
}

impl Series {
    fn new(label: String, color: RGBColor) -> Series {
        Series { label, points: Vec::new(), tags: Vec::new(), color, dashed: false, cross: false }
    }
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

/// A log-log plot written to `path`: the chart on the left, the legend in a column on the right. `fronts`
/// are drawn as thick grey lines behind the series.
fn draw(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    fronts: &[Vec<(f64, f64)>],
) -> Result<()> {
    font()?;
    let (w, h) = SIZE;
    let mut pixels = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area();
        let err = |e: DrawingAreaErrorKind<_>| anyhow!("drawing {}: {e}", path.display());
        root.fill(&WHITE).map_err(err)?;
        let (plot, legend_area) = root.split_horizontally(w - LEGEND_WIDTH);
        match bounds(series) {
            None => plot.draw(&Text::new(format!("{title}: no data"), (20, h as i32 / 2), (FONT, 20))).map_err(err)?,
            Some(((x0, x1), (y0, y1))) => {
                chart(&plot, title, x_desc, y_desc, series, fronts, (x0..x1, y0..y1)).map_err(err)?
            }
        }
        legend(&legend_area, series, !fronts.is_empty()).map_err(err)?;
        root.present().map_err(err)?;
    }
    save(path, pixels)
}

const LEGEND_WIDTH: u32 = 330;

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
type DrawResult = std::result::Result<(), DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>>;

fn legend(area: &Area, series: &[Series], front: bool) -> DrawResult {
    let grey = RGBColor(190, 190, 190);
    let mut y = 60;
    let mut entry = |label: &str, color: RGBColor, (dashed, cross): (bool, bool), thick: bool| -> DrawResult {
        let style = color.stroke_width(if thick { 8 } else { 2 });
        if cross {
            area.draw(&Cross::new((17, y), 6, color.stroke_width(3)))?;
        } else if dashed {
            area.draw(&PathElement::new(vec![(8, y), (14, y)], style))?;
            area.draw(&PathElement::new(vec![(20, y), (26, y)], style))?;
        } else {
            area.draw(&PathElement::new(vec![(8, y), (26, y)], style))?;
            area.draw(&Circle::new((17, y), 4, color.filled()))?;
        }
        area.draw(&Text::new(label.to_string(), (34, y - 7), (FONT, 13)))?;
        y += 20;
        Ok(())
    };
    if front {
        entry("Pareto front (per model)", grey, (false, false), true)?;
    }
    for s in series {
        entry(&s.label, s.color, (s.dashed, s.cross), false)?;
    }
    Ok(())
}

fn chart(
    root: &Area,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    fronts: &[Vec<(f64, f64)>],
    (x, y): (std::ops::Range<f64>, std::ops::Range<f64>),
) -> DrawResult {
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 18))
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
    for front in fronts {
        chart.draw_series(LineSeries::new(front.iter().copied(), RGBColor(190, 190, 190).stroke_width(8)))?;
    }
    for s in series {
        let style = s.color.stroke_width(2);
        if s.cross {
            chart.draw_series(s.points.iter().map(|&p| Cross::new(p, 7, s.color.stroke_width(3))))?;
        } else if s.dashed {
            chart.draw_series(DashedLineSeries::new(s.points.iter().copied(), 6, 6, style))?;
        } else {
            let line = if s.tags.is_empty() { s.points.clone() } else { Vec::new() };
            chart.draw_series(LineSeries::new(line, style))?;
            chart.draw_series(s.points.iter().map(|&p| Circle::new(p, 5, s.color.filled())))?;
        }
        let tags = s.points.iter().zip(&s.tags);
        chart.draw_series(tags.map(|(&p, tag)| Text::new(tag.clone(), p, (FONT, 13).into_font().color(&s.color))))?;
    }
    Ok(())
}

fn save(path: &Path, pixels: Vec<u8>) -> Result<()> {
    let image = image::RgbImage::from_raw(SIZE.0, SIZE.1, pixels).ok_or_else(|| anyhow!("plot buffer size"))?;
    let mut png = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    crate::report::write_file(path, &png)
}

fn config_label(r: &Record) -> String {
    let decoder = if r.k == 1 { r.decoder.clone() } else { format!("RP k={}", r.k) };
    format!("{} {decoder} {}", r.model, r.precision)
}

/// Lines per (model, k) over the f32 sweep records of one target view (f16 scales the same way; it is in the Pareto plot),
/// x and y taken by `point`, sorted by x.
fn by_config(records: &[Record], point: impl Fn(&Record) -> Option<(f64, f64)>) -> Vec<Series> {
    let mut series: Vec<Series> = Vec::new();
    for r in records.iter().filter(|r| r.group == "sweep" && r.precision == "f32" && r.target_views == 1) {
        let Some(p) = point(r) else { continue };
        let label = config_label(r);
        let next = COLORS[series.len() % COLORS.len()];
        match series.iter_mut().find(|s| s.label == label) {
            Some(s) => s.points.push(p),
            None => series.push(Series { points: vec![p], ..Series::new(label, next) }),
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

/// The Pareto plot's records: sweep records of one target view at 120x160 or, for a (model, k) not rendered
/// there (the accuracy run's small per-pixel renders, RP-DeFiNe), at its smallest size measured.
fn pareto_records(records: &[Record]) -> Vec<&Record> {
    let sweep: Vec<&Record> = records.iter().filter(|r| r.group == "sweep" && r.target_views == 1).collect();
    let pixels = |r: &Record| r.pixels;
    sweep
        .iter()
        .copied()
        .filter(|r| {
            let same = |o: &&&Record| o.model == r.model && o.k == r.k && o.max_err_f64_model.is_some();
            let sizes: Vec<&Record> = sweep.iter().filter(same).copied().collect();
            match sizes.iter().find(|o| o.target_size == PARETO_SIZE) {
                Some(_) => r.target_size == PARETO_SIZE,
                None => sizes.iter().map(|o| pixels(o)).min() == Some(r.pixels),
            }
        })
        .collect()
}

const PARETO_SIZE: &str = "120x160";

/// A series' label in the Pareto plot: model and precision, with the kernel family for f16-act (the tensor
/// kernels or not).
fn pareto_label(r: &Record) -> String {
    if r.precision == "f16-act" && !r.kernel.is_empty() {
        format!("{} f16-act {}", r.model, r.kernel)
    } else {
        format!("{} {}", r.model, r.precision)
    }
}

/// A point's tag: k (or the per-pixel decoder), and the size where it is not the plot's.
fn pareto_tag(r: &Record) -> String {
    let config = if r.k == 1 { r.decoder.clone() } else { format!("k={}", r.k) };
    if r.target_size == PARETO_SIZE {
        format!(" {config}")
    } else {
        format!(" {config} {}", r.target_size)
    }
}

pub fn draw_all(records: &[Record], out: &Path) -> Result<()> {
    // Render time against rgb error against the float64 model, at one target size (the paper's 120×160; a model
    // not rendered there at its smallest), over k, precision and kernels; PyTorch's bf16 autocast at its own
    // render time, where measured.
    let mut pareto: Vec<Series> = Vec::new();
    let mut add = |label: String, point: (f64, f64), tag: String, cross: bool| {
        let next = COLORS[pareto.len() % COLORS.len()];
        let s = match pareto.iter_mut().position(|s| s.label == label) {
            Some(i) => &mut pareto[i],
            None => {
                pareto.push(Series { cross, ..Series::new(label, next) });
                pareto.last_mut().expect("just pushed")
            }
        };
        s.points.push(point);
        s.tags.push(tag);
    };
    let chosen = pareto_records(records);
    for r in &chosen {
        if let (Some(t), Some(e)) = (r.render_ms, r.max_err_f64_model) {
            add(pareto_label(r), (t.median_ms, e.max(1e-9)), pareto_tag(r), false);
        }
    }
    for r in &chosen {
        if let (Some(t), Some(e)) = (r.pytorch_autocast_render_ms, r.max_err_autocast_f64_model) {
            add(format!("{} PyTorch bf16 autocast", r.model), (t.median_ms, e.max(1e-9)), pareto_tag(r), true);
        }
    }
    // One front per model over the engine's choices (k, precision, kernels): not PyTorch's points.
    let mut models: Vec<&str> = pareto.iter().filter(|s| !s.cross).filter_map(|s| s.label.split(' ').next()).collect();
    models.dedup();
    let fronts: Vec<Vec<(f64, f64)>> = models
        .iter()
        .map(|m| {
            let points: Vec<(f64, f64)> = pareto
                .iter()
                .filter(|s| !s.cross && s.label.starts_with(&format!("{m} ")))
                .flat_map(|s| s.points.clone())
                .collect();
            pareto_front(&points)
        })
        .collect();
    draw(
        &out.join(FILES[0]),
        &format!("Render time against rgb error vs the float64 model ({PARETO_SIZE}, or each model's smallest size)"),
        "render time (ms)",
        "max |rgb - float64 model|",
        &pareto,
        &fronts,
    )?;
    draw(
        &out.join(FILES[1]),
        "Frames per second against resolution",
        "pixels per frame (1 target view)",
        "frames per second",
        &by_config(records, |r| r.fps.map(|f| (r.pixels as f64, f))),
        &[],
    )?;
    // Beside the engine's planned peaks (solid), what the official SRT and RP-SRT k=16 would hold in softmax
    // scores if they materialised them (dashed, the paper's Figure 2a quantity).
    let mut memory = by_config(records, |r| r.render_peak_bytes.map(|b| (r.pixels as f64, b as f64)));
    let scores = by_config(records, |r| {
        (r.model == "official" && (r.k == 1 || r.k == 16)).then_some((r.pixels as f64, r.attention_scores_bytes as f64))
    });
    for s in scores {
        let color = memory.iter().find(|m| m.label == s.label).map_or(s.color, |m| m.color);
        memory.push(Series { label: format!("{}: scores", s.label), color, dashed: true, ..s });
    }
    draw(
        &out.join(FILES[2]),
        "Planned peak GPU memory of a render",
        "pixels per frame (1 target view)",
        "bytes",
        &memory,
        &[],
    )
}

#[cfg(test)]
mod tests {
    use super::{pareto_front, pareto_label, pareto_records, pareto_tag};
    use crate::report::Record;

    fn record(model: &str, k: usize, size: &str, pixels: usize, err: Option<f64>) -> Record {
        Record {
            group: "sweep".into(),
            model: model.into(),
            decoder: if k == 1 { "SRT".into() } else { "RP-SRT".into() },
            k,
            precision: "f32".into(),
            target_views: 1,
            target_size: size.into(),
            pixels,
            max_err_f64_model: err,
            ..Default::default()
        }
    }

    #[test]
    fn the_pareto_plot_takes_120x160_or_each_model_s_smallest_size() {
        let records = [
            record("official", 8, "120x160", 19200, Some(1e-3)),
            record("official", 8, "240x320", 76800, Some(1e-3)),
            record("official", 1, "60x80", 4800, None),
            record("official", 1, "24x32", 768, Some(3e-4)),
            record("official", 1, "48x64", 3072, Some(3e-4)),
            Record { target_views: 8, ..record("official", 1, "24x32", 768, Some(3e-4)) },
        ];
        let chosen: Vec<(usize, &str)> =
            pareto_records(&records).iter().map(|r| (r.k, r.target_size.as_str())).collect();
        assert_eq!(chosen, [(8, "120x160"), (1, "24x32")]);
        assert_eq!(pareto_tag(&records[0]), " k=8");
        assert_eq!(pareto_tag(&records[3]), " SRT 24x32");
    }

    #[test]
    fn f16_act_series_name_their_kernels() {
        let coop = Record { precision: "f16-act".into(), kernel: "Coop".into(), ..record("official", 8, "", 0, None) };
        assert_eq!(pareto_label(&coop), "official f16-act Coop");
        assert_eq!(pareto_label(&record("official", 8, "", 0, None)), "official f32");
    }

    #[test]
    fn the_front_keeps_only_undominated_points() {
        let points = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (0.5, 9.0)];
        assert_eq!(pareto_front(&points), vec![(0.5, 9.0), (1.0, 5.0), (2.0, 3.0), (4.0, 1.0)]);
    }
}
