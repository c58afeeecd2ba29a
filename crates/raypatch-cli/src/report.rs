//! What a run prints besides its one-line summary: metrics against the ground truth (--metrics), op
//! profiles (--profile) and time summaries (--timings).

use std::time::Duration;

use anyhow::{Context, Result};
use raypatch::raypatch_engine::gpu::CounterSnapshot;
use raypatch::{metrics, Image, OpTimes, PipelineCacheStatus, Region, Rendered};

/// The ground truth of one rendered view, when the scene has it.
pub struct Truth<'a> {
    pub label: &'a str,
    pub image: Option<&'a Image>,
    /// Object ids `[H, W]` of the whole image (0 = background).
    pub masks: Option<&'a [u32]>,
    /// Depth `[H, W]` of the whole image, in metres (0 = none).
    pub depth: Option<&'a [f32]>,
}

/// The values of `values` (`[H, width]` of the whole image) inside `region`.
fn crop<T: Copy>(values: &[T], width: usize, region: Region) -> Vec<T> {
    (region.y..region.y + region.height)
        .flat_map(|y| values[y * width + region.x..y * width + region.x + region.width].iter().copied())
        .collect()
}

/// Per view: PSNR and SSIM of the rgb against the ground-truth image, FG-ARI of the segmentation against the
/// object masks, Abs.Rel, Sq.Rel and RMSE of the depth against the ground-truth depth (each where both exist);
/// then their means, the FG-ARI of all views pooled, as the official OSRT test step computes it per scene,
/// and the depth errors of all views together as the official test step reports them
/// ([`metrics::pool_depth_errors`]). `width` is the full image's width (masks and depths are of the whole
/// image; a region render is scored on the region).
pub fn metrics(truths: &[Truth], rendered: &[Rendered], width: usize) -> Result<Vec<String>> {
    let mut lines = Vec::new();
    let (mut psnrs, mut ssims, mut aris) = (Vec::new(), Vec::new(), Vec::new());
    let (mut pooled_ids, mut pooled_weights, mut slots) = (Vec::new(), Vec::new(), 0);
    let mut depths = Vec::new();
    for (truth, frame) in truths.iter().zip(rendered) {
        let mut parts = Vec::new();
        if let (Some(image), Some(rgb)) = (truth.image, frame.rgb()) {
            let image = if (image.width(), image.height()) == (rgb.width(), rgb.height()) {
                image.clone()
            } else {
                image.crop(frame.region)?
            };
            let (p, s) = (
                metrics::psnr(&rgb, &image)?,
                metrics::ssim(&rgb, &image).with_context(|| format!("--metrics: {}", truth.label))?,
            );
            parts.push(format!("PSNR {p:.3} dB, SSIM {s:.4}"));
            psnrs.push(p);
            ssims.push(s);
        }
        if let (Some(masks), Some((weights, n))) = (truth.masks, frame.segmentation()) {
            let ids = crop(masks, width, frame.region);
            let ari = metrics::fg_ari(&ids, weights, n)?;
            parts.push(format!("FG-ARI {ari:.4}"));
            aris.push(ari);
            pooled_ids.extend(ids);
            pooled_weights.extend_from_slice(weights);
            slots = n;
        }
        if let (Some(truth), Some(depth)) = (truth.depth, frame.depth()) {
            let e = metrics::depth_errors(depth, &crop(truth, width, frame.region))?;
            parts.push(depth_text(&e));
            depths.push(e);
        }
        lines.push(format!("{}: {}", truth.label, parts.join(", ")));
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let mut summary = Vec::new();
    if !psnrs.is_empty() {
        summary.push(format!("PSNR {:.3} dB, SSIM {:.4}", mean(&psnrs), mean(&ssims)));
    }
    if !aris.is_empty() {
        let pooled = metrics::fg_ari(&pooled_ids, &pooled_weights, slots)?;
        summary.push(format!("FG-ARI {:.4} (all views pooled, as the official test: {pooled:.4})", mean(&aris)));
    }
    if !depths.is_empty() {
        let pooled = metrics::pool_depth_errors(&depths);
        summary.push(format!(
            "depth of all views as the official test (pixels pooled; RMSE per view, weighted by pixels): {}",
            depth_text(&pooled)
        ));
    }
    lines.push(format!("mean over {} view(s): {}", truths.len(), summary.join(", ")));
    Ok(lines)
}

/// "Abs.Rel A, Sq.Rel S, RMSE R m over N pixels with depth".
fn depth_text(e: &metrics::DepthErrors) -> String {
    if e.pixels == 0 {
        return "no pixel with ground-truth depth".into();
    }
    format!(
        "Abs.Rel {:.4}, Sq.Rel {:.4}, RMSE {:.4} m over {} pixels with depth",
        e.abs_rel, e.sq_rel, e.rmse, e.pixels
    )
}

/// The slowest ops of a plan, with their share of the plan's total.
pub fn print_profile(what: &str, ops: &OpTimes) {
    let total: f64 = ops.iter().map(|(_, t)| t.as_secs_f64()).sum();
    println!("{what}: {} ops, {:.1} ms run one by one; slowest:", ops.len(), total * 1e3);
    let mut sorted: Vec<_> = ops.iter().collect();
    sorted.sort_by_key(|(_, t)| std::cmp::Reverse(*t));
    for (label, t) in sorted.iter().take(12) {
        println!("  {:8.2} ms {:5.1}%  {label}", ms(*t), 100.0 * t.as_secs_f64() / total);
    }
}

/// "pipelines: N compiled in T ms; pipeline cache FILE (K KiB loaded)", or "; no pipeline cache: WHY".
pub fn pipelines(counters: &CounterSnapshot, cache: &PipelineCacheStatus) -> String {
    format!(
        "pipelines: {} compiled in {:.1} ms (part of load, encode and render plan); {cache}",
        counters.pipelines_compiled,
        ms(Duration::from_nanos(counters.pipeline_compile_nanos))
    )
}

pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// "median M ms, min A ms, max B ms over N runs".
pub fn summary(times: &[Duration]) -> String {
    let mut sorted = times.to_vec();
    sorted.sort();
    format!(
        "median {:.1} ms, min {:.1} ms, max {:.1} ms over {} runs",
        ms(sorted[sorted.len() / 2]),
        ms(sorted[0]),
        ms(sorted[sorted.len() - 1]),
        sorted.len()
    )
}
