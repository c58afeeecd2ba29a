//! Image quality against ground truth: PSNR and SSIM on [0, 1] images, as torchmetrics computes them
//! (`PeakSignalNoiseRatio(data_range=1.0)`, `StructuralSimilarityIndexMeasure(data_range=1.0)`), in f64.

use crate::error::{Error, Result};
use crate::image::Image;

/// Side of SSIM's Gaussian window, and its standard deviation.
pub const SSIM_WINDOW: usize = 11;
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

/// Structural similarity: the standard SSIM map with an 11×11 Gaussian window (σ = 1.5) over every position
/// where the window fits inside the image, averaged over positions and channels. Both images need at least
/// 11×11 pixels.
///
/// ```
/// use raypatch::{metrics::ssim, Image};
/// let a = Image::new(11, 11, vec![0.2; 11 * 11 * 3])?;
/// let b = Image::new(11, 11, vec![0.4; 11 * 11 * 3])?;
/// assert!((ssim(&a, &a)? - 1.0).abs() < 1e-12);
/// // Constant images: only the luminance term is left, (2·μa·μb + C1) / (μa² + μb² + C1).
/// let expected = (2.0 * 0.2 * 0.4 + 1e-4) / (0.04 + 0.16 + 1e-4);
/// assert!((ssim(&a, &b)? - expected).abs() < 1e-6);
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn ssim(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    let (width, height) = (a.width(), a.height());
    if width < SSIM_WINDOW || height < SSIM_WINDOW {
        return Err(Error::Metrics(format!("SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {width}x{height}")));
    }
    let window = gaussian_window();
    let (ow, oh) = (width - SSIM_WINDOW + 1, height - SSIM_WINDOW + 1);
    // Gaussian-weighted local means of x, y, x², y², xy: rows first, then columns ("valid" positions only).
    let blur = |values: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let mut rows = vec![0.0; height * ow];
        for y in 0..height {
            for x in 0..ow {
                rows[y * ow + x] = (0..SSIM_WINDOW).map(|k| window[k] * values(y * width + x + k)).sum();
            }
        }
        let mut out = vec![0.0; oh * ow];
        for y in 0..oh {
            for x in 0..ow {
                out[y * ow + x] = (0..SSIM_WINDOW).map(|k| window[k] * rows[(y + k) * ow + x]).sum();
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
        for p in 0..oh * ow {
            let (vx, vy, cov) = (mxx[p] - mx[p] * mx[p], myy[p] - my[p] * my[p], mxy[p] - mx[p] * my[p]);
            let luminance = (2.0 * mx[p] * my[p] + SSIM_C1) / (mx[p] * mx[p] + my[p] * my[p] + SSIM_C1);
            let structure = (2.0 * cov + SSIM_C2) / (vx + vy + SSIM_C2);
            total += luminance * structure;
        }
    }
    Ok(total / (3 * oh * ow) as f64)
}
