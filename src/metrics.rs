//! Quality against ground truth, in f64: PSNR and SSIM on [0, 1] images, as torchmetrics computes them
//! (`PeakSignalNoiseRatio(data_range=1.0)`, `StructuralSimilarityIndexMeasure(data_range=1.0)`); FG-ARI of a
//! segmentation; depth errors (Abs.Rel, Sq.Rel, RMSE) as the official test step computes them.

use crate::error::{Error, Result};
use crate::image::{slot_ids, Image};

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

/// Depth errors of one view, or of several pooled ([`pool_depth_errors`]), over the pixels with ground truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthErrors {
    /// Absolute relative difference: mean of |d − t| / t.
    pub abs_rel: f64,
    /// Square relative difference: mean of (d − t)² / t.
    pub sq_rel: f64,
    /// Root mean square error in metres: √(mean of (d − t)²) for one view; for pooled views, the views' RMSEs
    /// averaged with their pixel counts as weights.
    pub rmse: f64,
    /// Pixels with ground truth (t > 0); the figures are NaN when there are none.
    pub pixels: usize,
}

/// Depth errors of a predicted depth `d` against ground truth `t` (both in metres, one value per pixel), as the
/// official DeFiNe / SRT test step computes them (`GenericModel.test_step` of tberriel/RayPatchQuerying), over
/// the pixels with ground truth: t > 0 (and finite; the official loader's depth maps hold 0 where ScanNet has
/// none, and its test-time visibility mask keeps every pixel). Accumulated in f64.
///
/// - **Abs.Rel** `absDiff_d` = `AbsoluteRelativeDifference(pred_log=True, target_log=True)(logdepth,
///   log t)`: mean of |exp(logdepth) − t| / t. The official call takes the log of t and exponentiates it back;
///   here t is used as given (they differ by float32 rounding).
/// - **Sq.Rel** `squareDiff_d` = `SquareRelativeDifference(...)`: mean of (d − t)² / t (divided by t, not t²).
/// - **RMSE** `rmse_d`: not on log depths: the test step computes √(Σ (exp(logdepth) − t)² / n) per image
///   over its valid pixels, in metres (the validation step feeds `MeanSquaredError(squared=False)` the
///   same depths, `log_depth.exp()` and t, but pools all pixels of the batch).
///
/// `predicted` is `exp(logdepth)` ([`crate::Output::Depth`]); a non-finite prediction at a valid pixel makes
/// the figures NaN, as it would the official ones.
///
/// ```
/// use raypatch::metrics::depth_errors;
/// let truth = [1.0, 2.0, 0.0, 4.0]; // the third pixel has no ground truth
/// let predicted = [1.5, 2.0, 9.0, 3.0];
/// let e = depth_errors(&predicted, &truth)?;
/// assert_eq!(e.pixels, 3);
/// assert!((e.abs_rel - (0.5 / 1.0 + 0.0 + 1.0 / 4.0) / 3.0).abs() < 1e-12);
/// assert!((e.sq_rel - (0.25 / 1.0 + 0.0 + 1.0 / 4.0) / 3.0).abs() < 1e-12);
/// assert!((e.rmse - ((0.25 + 0.0 + 1.0) / 3.0f64).sqrt()).abs() < 1e-12);
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn depth_errors(predicted: &[f32], truth: &[f32]) -> Result<DepthErrors> {
    if predicted.len() != truth.len() {
        return Err(Error::Metrics(format!(
            "depth: {} predicted values for {} ground-truth pixels",
            predicted.len(),
            truth.len()
        )));
    }
    let (mut abs_rel, mut sq_rel, mut squares, mut pixels) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for (&d, &t) in predicted.iter().zip(truth) {
        if !(t.is_finite() && t > 0.0) {
            continue;
        }
        let (d, t) = (f64::from(d), f64::from(t));
        let e = d - t;
        abs_rel += e.abs() / t;
        sq_rel += e * e / t;
        squares += e * e;
        pixels += 1;
    }
    let n = pixels as f64;
    Ok(DepthErrors { abs_rel: abs_rel / n, sq_rel: sq_rel / n, rmse: (squares / n).sqrt(), pixels })
}

/// The depth errors of several views of one scene taken together, as the official test step reports a batch
/// of target views: Abs.Rel and Sq.Rel over all their valid pixels pooled (the mean of the views' figures
/// weighted by their pixel counts), RMSE the views' RMSEs weighted by their pixel counts (`rmse_d_avg`; with
/// one scene per batch, each target view's RMSE is `rmse_d_i`). Views without ground truth count for nothing.
///
/// ```
/// use raypatch::metrics::{depth_errors, pool_depth_errors};
/// let a = depth_errors(&[2.0], &[1.0])?; // |e| = 1 over 1 pixel
/// let b = depth_errors(&[3.0, 3.0, 3.0], &[3.0, 3.0, 3.0])?; // exact over 3 pixels
/// let all = pool_depth_errors(&[a, b]);
/// assert_eq!(all.pixels, 4);
/// assert!((all.abs_rel - 0.25).abs() < 1e-12 && (all.rmse - 0.25).abs() < 1e-12);
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn pool_depth_errors(views: &[DepthErrors]) -> DepthErrors {
    let counted = || views.iter().filter(|v| v.pixels > 0);
    let pixels: usize = counted().map(|v| v.pixels).sum();
    let mean =
        |figure: fn(&DepthErrors) -> f64| counted().map(|v| figure(v) * v.pixels as f64).sum::<f64>() / pixels as f64;
    DepthErrors { abs_rel: mean(|v| v.abs_rel), sq_rel: mean(|v| v.sq_rel), rmse: mean(|v| v.rmse), pixels }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two views by hand; the figures equal those of the official test-step code (criterions.py and
    /// `GenericModel.test_step`) run in PyTorch on the same values (one scene, the two views as its targets):
    /// Abs.Rel 0.4375, Sq.Rel 0.9375, RMSE per view 0.8164966 and 3, rmse_d_avg 1.3623724.
    #[test]
    fn depth_errors_by_hand_and_pooled_as_the_official_test() {
        // Ground truth 0 and NaN are no depth: the pixels predicted 5 and 7 count for nothing.
        let a = depth_errors(&[1.0, 5.0, 5.0, 7.0, 1.0], &[2.0, 0.0, 4.0, f32::NAN, 1.0]).unwrap();
        assert_eq!(a.pixels, 3);
        // |1-2|/2 = 0.5, |5-4|/4 = 0.25, 0; squares 1/2, 1/4, 0; errors² 1, 1, 0.
        assert!((a.abs_rel - 0.25).abs() < 1e-15);
        assert!((a.sq_rel - 0.25).abs() < 1e-15);
        assert!((a.rmse - (2.0f64 / 3.0).sqrt()).abs() < 1e-15);
        let b = depth_errors(&[6.0], &[3.0]).unwrap();
        assert_eq!((b.abs_rel, b.sq_rel, b.rmse, b.pixels), (1.0, 3.0, 3.0, 1));
        let pooled = pool_depth_errors(&[a, b]);
        assert_eq!(pooled.pixels, 4);
        assert!((pooled.abs_rel - 0.4375).abs() < 1e-15);
        assert!((pooled.sq_rel - 0.9375).abs() < 1e-15);
        assert!((pooled.rmse - (3.0 * (2.0f64 / 3.0).sqrt() + 3.0) / 4.0).abs() < 1e-15);
        assert!((pooled.rmse - 1.3623724).abs() < 1e-6);
        // A view without ground truth: NaN figures, ignored when pooling.
        let none = depth_errors(&[1.0, 2.0], &[0.0, -1.0]).unwrap();
        assert_eq!(none.pixels, 0);
        assert!(none.abs_rel.is_nan() && none.rmse.is_nan());
        assert_eq!(pool_depth_errors(&[a, b, none]), pooled);
        assert!(depth_errors(&[1.0], &[1.0, 2.0]).unwrap_err().to_string().contains("1 predicted values for 2"));
    }
}
