//! Image quality against ground truth: PSNR and SSIM on [0, 1] images, as torchmetrics computes them
//! (`PeakSignalNoiseRatio(data_range=1.0)`, `StructuralSimilarityIndexMeasure(data_range=1.0)`), in f64.

use crate::error::{Error, Result};
use crate::image::Image;

/// Side of SSIM's Gaussian window.
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of SSIM's Gaussian window.
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM's stabilising constants for a data range of 1: (0.01)² and (0.03)².
const SSIM_C1: f64 = 0.01 * 0.01;
const SSIM_C2: f64 = 0.03 * 0.03;

fn same_size(a: &Image, b: &Image) -> Result<()> {
    if (a.width(), a.height()) != (b.width(), b.height()) {
        return Err(Error::Metrics(format!(
            "images of different sizes: {}x{} and {}x{}",
            a.width(),
            a.height(),
            b.width(),
            b.height()
        )));
    }
    Ok(())
}

/// Peak signal-to-noise ratio in dB for a data range of 1: `10·log10(1 / MSE)` over all pixels and
/// channels (infinite for identical images).
///
/// ```
/// use raypatch::{metrics::psnr, Image};
/// let a = Image::new(1, 1, vec![0.5, 0.5, 0.5])?;
/// let b = Image::new(1, 1, vec![0.6, 0.4, 0.5])?;
/// // MSE = (0.01 + 0.01 + 0) / 3
/// assert!((psnr(&a, &b)? - 10.0 * (3.0f64 / 0.02).log10()).abs() < 1e-5);
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn psnr(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    let sum: f64 = a.data().iter().zip(b.data()).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum();
    let mse = sum / a.data().len().max(1) as f64;
    Ok(10.0 * (1.0 / mse).log10())
}

/// The normalised 1-D Gaussian of SSIM's window.
fn gaussian_window() -> [f64; SSIM_WINDOW] {
    let mut w = [0.0; SSIM_WINDOW];
    let centre = (SSIM_WINDOW / 2) as f64;
    for (i, v) in w.iter_mut().enumerate() {
        let d = i as f64 - centre;
        *v = (-(d / SSIM_SIGMA).powi(2) / 2.0).exp();
    }
    let total: f64 = w.iter().sum();
    w.map(|v| v / total)
}

/// Index `i` (from `-pad` to `n - 1 + pad`) mirrored into `0..n` without repeating the edge, like
/// PyTorch's `reflect` padding.
fn reflect(i: isize, n: usize) -> usize {
    let last = n as isize - 1;
    (if i < 0 {
        -i
    } else if i > last {
        2 * last - i
    } else {
        i
    }) as usize
}

/// Structural similarity as torchmetrics (1.x) computes it: the SSIM map with an 11×11 Gaussian window
/// (σ = 1.5) at every pixel, the image extended by reflection (without repeating the edge) where the window
/// leaves it, variances clamped at 0; averaged over pixels and channels. Both images need at least 6×6
/// pixels (the reflection needs more pixels than the window's radius).
///
/// ```
/// use raypatch::{metrics::ssim, Image};
/// let a = Image::new(8, 6, vec![0.2; 8 * 6 * 3])?;
/// let b = Image::new(8, 6, vec![0.4; 8 * 6 * 3])?;
/// assert!((ssim(&a, &a)? - 1.0).abs() < 1e-12);
/// // Constant images: only the luminance term is left, (2·μa·μb + C1) / (μa² + μb² + C1).
/// let expected = (2.0 * 0.2 * 0.4 + 1e-4) / (0.04 + 0.16 + 1e-4);
/// assert!((ssim(&a, &b)? - expected).abs() < 1e-6);
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn ssim(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    let (width, height) = (a.width(), a.height());
    let radius = SSIM_WINDOW / 2;
    if width <= radius || height <= radius {
        return Err(Error::Metrics(format!(
            "SSIM needs images of at least {0}x{0} pixels, got {width}x{height}",
            radius + 1
        )));
    }
    let window = gaussian_window();
    let tap = |centre: usize, k: usize, n: usize| reflect(centre as isize + k as isize - radius as isize, n);
    // Gaussian-weighted local means of a value per pixel: along rows, then along columns.
    let blur = |values: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let mut rows = vec![0.0; height * width];
        for y in 0..height {
            for x in 0..width {
                rows[y * width + x] = (0..SSIM_WINDOW).map(|k| window[k] * values(y * width + tap(x, k, width))).sum();
            }
        }
        let mut out = vec![0.0; height * width];
        for y in 0..height {
            for x in 0..width {
                out[y * width + x] = (0..SSIM_WINDOW).map(|k| window[k] * rows[tap(y, k, height) * width + x]).sum();
            }
        }
        out
    };
    let mut total = 0.0;
    for c in 0..3 {
        let x = |i: usize| a.data()[i * 3 + c] as f64;
        let y = |i: usize| b.data()[i * 3 + c] as f64;
        let (mx, my) = (blur(&x), blur(&y));
        let (mxx, myy, mxy) = (blur(&|i| x(i) * x(i)), blur(&|i| y(i) * y(i)), blur(&|i| x(i) * y(i)));
        for p in 0..width * height {
            let vx = (mxx[p] - mx[p] * mx[p]).max(0.0);
            let vy = (myy[p] - my[p] * my[p]).max(0.0);
            let cov = mxy[p] - mx[p] * my[p];
            let luminance = (2.0 * mx[p] * my[p] + SSIM_C1) / (mx[p] * mx[p] + my[p] * my[p] + SSIM_C1);
            let structure = (2.0 * cov + SSIM_C2) / (vx + vy + SSIM_C2);
            total += luminance * structure;
        }
    }
    Ok(total / (3 * width * height) as f64)
}

/// Each pixel's most-weighted slot, from slot weights `[pixels, slots]` (the first one on ties, as `argmax`).
pub fn slot_ids(weights: &[f32], slots: usize) -> impl Iterator<Item = usize> + '_ {
    weights.chunks_exact(slots).map(|w| {
        w.iter().enumerate().fold((0, f32::NEG_INFINITY), |best, (i, &v)| if v > best.1 { (i, v) } else { best }).0
    })
}

/// Foreground adjusted Rand index of a predicted segmentation against ground-truth object ids, as the
/// official OSRT code computes it (`compute_adjusted_rand_index` of tberriel/RayPatchQuerying, after
/// DeepMind's multi_object_datasets): pixels whose true id is 0 (background) are left out; each pixel's
/// predicted group is the slot with the largest weight (the first one on ties, as `argmax`); the ARI is
/// computed from the contingency table in f64, and is 1 when both the true and the predicted foreground are a
/// single group (where the formula divides 0 by 0). Pass every target view of a scene at once to get the
/// official per-scene figure (its test step pools both target views).
///
/// `true_ids`: one id per pixel; `weights`: `[pixels, slots]` row-major.
///
/// ```
/// use raypatch::metrics::fg_ari;
/// // Two objects, predicted by two slots: perfect, whatever the slot numbers; the background pixel is ignored.
/// let truth = [1, 1, 2, 2, 0];
/// let weights = [0.1, 0.9, 0.2, 0.8, 0.7, 0.3, 0.6, 0.4, 0.5, 0.5];
/// assert!((fg_ari(&truth, &weights, 2)? - 1.0).abs() < 1e-12);
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn fg_ari(true_ids: &[u32], weights: &[f32], slots: usize) -> Result<f64> {
    if slots == 0 || weights.len() != true_ids.len() * slots {
        return Err(Error::Metrics(format!(
            "FG-ARI: {} slot weights for {} pixels of {slots} slots",
            weights.len(),
            true_ids.len()
        )));
    }
    let predicted = slot_ids(weights, slots);
    // Contingency counts over foreground pixels: (true id, predicted slot) -> n.
    let mut table: std::collections::HashMap<(u32, usize), f64> = std::collections::HashMap::new();
    for (&truth, pred) in true_ids.iter().zip(predicted) {
        if truth != 0 {
            *table.entry((truth, pred)).or_default() += 1.0;
        }
    }
    let mut true_sums: std::collections::HashMap<u32, f64> = std::collections::HashMap::new();
    let mut pred_sums: std::collections::HashMap<usize, f64> = std::collections::HashMap::new();
    for (&(t, p), &n) in &table {
        *true_sums.entry(t).or_default() += n;
        *pred_sums.entry(p).or_default() += n;
    }
    if true_sums.len() <= 1 && pred_sums.len() <= 1 {
        return Ok(1.0);
    }
    let pairs = |counts: &mut dyn Iterator<Item = f64>| counts.map(|n| n * (n - 1.0)).sum::<f64>();
    let points: f64 = table.values().sum();
    let rindex = pairs(&mut table.values().copied());
    let aindex = pairs(&mut pred_sums.values().copied());
    let bindex = pairs(&mut true_sums.values().copied());
    let expected = aindex * bindex / (points * (points - 1.0));
    let max = (aindex + bindex) / 2.0;
    Ok((rindex - expected) / (max - expected))
}
