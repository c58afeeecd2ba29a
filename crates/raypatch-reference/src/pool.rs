//! Float64 reference of PyTorch's `F.max_pool2d(x, kernel, stride, padding)` (dilation 1,
//! `ceil_mode=False`) on NHWC images.

use raypatch_engine::kernels::pool::pool_output_size;
use raypatch_engine::kernels::Window;

/// Max pool of `x`, NHWC `[n*h*w, c]`, to `[n*ho*wo, c]` with `ho = (h + 2·padding − k) / stride + 1`: each
/// output is the maximum of the input pixels its window covers (the padding is −∞).
pub fn max_pool2d(x: &[f64], (n, h, w): (usize, usize, usize), c: usize, window: Window) -> Vec<f64> {
    let Window { kernel: k, stride, padding } = window;
    assert_eq!(x.len(), n * h * w * c, "max_pool2d reference: x is not [n*h*w, c]");
    let (ho, wo) = pool_output_size(h, w, window).expect("max_pool2d reference: the window does not fit");
    // The input indices an axis of `size` covers for output `o`.
    let span = |o: usize, size: usize| {
        (o * stride).saturating_sub(padding)..(o * stride + k).saturating_sub(padding).min(size)
    };
    let mut out = Vec::with_capacity(n * ho * wo * c);
    for b in 0..n {
        for oy in 0..ho {
            for ox in 0..wo {
                for ch in 0..c {
                    let mut m = f64::NEG_INFINITY;
                    for iy in span(oy, h) {
                        for ix in span(ox, w) {
                            m = m.max(x[((b * h + iy) * w + ix) * c + ch]);
                        }
                    }
                    out.push(m);
                }
            }
        }
    }
    out
}
