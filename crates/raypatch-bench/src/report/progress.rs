//! The progress line printed as each configuration is measured, so that a log cut short still holds every
//! comparison made.

use super::tables::{bytes, host_ms, sci};
use super::Record;
use crate::measure::Stats;

/// When the run started, for the progress lines.
pub fn started() -> std::time::Instant {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    *START.get_or_init(std::time::Instant::now)
}

/// The progress line of a measured configuration: the engine's figures, then its render's wall time and
/// PyTorch's where measured (so that a log cut short still holds every comparison made).
pub fn print_row(r: &Record) {
    let ms = |s: Option<Stats>| s.map_or("-".to_string(), |s| format!("{:.2}", s.median_ms));
    let mut compared = String::new();
    if let Some(wall) = r.render_wall_ms {
        compared += &format!("; wall {:.2} ms", wall.median_ms);
    }
    if let Some(host) = host_ms(r) {
        compared += &format!(" (host {host:.2} ms)");
    }
    if let Some(buffers) = r.render_buffers_per_run.filter(|b| *b > 0.0) {
        compared += &format!("; {buffers:.1} buffers allocated per render");
    }
    if r.pytorch_render_ms.is_some() || r.pytorch_compiled_render_ms.is_some() {
        compared += &format!(
            "; PyTorch render {} ms (compiled {}), encode {} ms (compiled {})",
            ms(r.pytorch_render_ms),
            ms(r.pytorch_compiled_render_ms),
            ms(r.pytorch_encode_ms),
            ms(r.pytorch_compiled_encode_ms)
        );
    }
    println!(
        "  [{:>5.0} s] {:<12} {:<7} k={:<2} {} {:>2}x{:>9} {:<32} render {:>9.2} ms ({:>8.1} fps), encode {:>8.1} ms, peak {:>9}, err {}{}{compared}",
        started().elapsed().as_secs_f64(),
        r.model,
        r.decoder,
        r.k,
        r.precision,
        r.target_views,
        r.target_size,
        r.variant,
        r.render_ms.map_or(0.0, |s| s.median_ms),
        r.fps.unwrap_or(0.0),
        r.encode_ms.map_or(0.0, |e| e.median_ms),
        r.render_peak_bytes.map_or("-".into(), bytes),
        sci(r.max_err_f64_reference),
        error_vs_model(r),
    );
}

/// The progress line's errors against the float64 model (rgb, and log-depth and mask where measured).
fn error_vs_model(r: &Record) -> String {
    let mut text = String::new();
    if let Some(e) = r.max_err_f64_model {
        text += &format!(" (vs f64 model {e:.1e}");
        for (name, e) in [("log-depth", r.max_err_logdepth_f64_model), ("mask", r.max_err_segmentation_f64_model)] {
            if let Some(e) = e {
                text += &format!(", {name} {e:.1e}");
            }
        }
        text += ")";
    }
    text
}
