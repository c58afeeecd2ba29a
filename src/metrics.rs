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
