//! Float64 reference of the K×K convolution (PyTorch `nn.Conv2d(cin, cout, k, stride, padding)`, optionally
//! preceded by `nn.Upsample(scale_factor=2, mode='nearest')`) with a fused activation and the three ways of
//! meeting the output ([`ConvMode`]), on NHWC images.

use crate::activation;
use raypatch_engine::kernels::{conv_output_size, ConvMode};
use raypatch_engine::kernels::{Activation, Window};

/// Convolves `x` with `weight` into `out` as `mode` says: `act(conv + bias)`, `out + act(conv + bias)`, or
/// `act(out + conv + bias)`, zero padding `window.padding` on every side, stride `window.stride`.
///
/// `x` is NHWC `[n*h*w, cin]`; `weight` is PyTorch's `[cout, cin, k, k]`; `bias` is `[cout]`; `out` is
/// `[n*ho*wo, cout]` (its contents are read unless `mode` is [`ConvMode::Overwrite`]). With `upsample_input`
/// the convolution runs on the 2× nearest upsampling of `x` (a `2h × 2w` image whose pixel `(y, x)` is
/// `x[y / 2, x / 2]`). `ho = (h' + 2·padding − k) / stride + 1`, `h'` the height the convolution sees
/// ([`conv_output_size`]).
#[allow(clippy::too_many_arguments)]
pub fn conv2d(
    x: &[f64],
    (n, h, w): (usize, usize, usize),
    cin: usize,
    weight: &[f64],
    bias: Option<&[f64]>,
    cout: usize,
    window: Window,
    upsample_input: bool,
    act: Activation,
    mode: ConvMode,
    out: &mut [f64],
) {
    let Window { kernel: k, stride, padding } = window;
    assert_eq!(x.len(), n * h * w * cin, "conv2d reference: x is not [n*h*w, cin]");
    assert_eq!(weight.len(), cout * cin * k * k, "conv2d reference: weight is not [cout, cin, k, k]");
    let up = if upsample_input { 2 } else { 1 };
    let (he, we) = (h * up, w * up);
    let (ho, wo) = conv_output_size(h, w, window, upsample_input).expect("conv2d reference: the window does not fit");
    assert_eq!(out.len(), n * ho * wo * cout, "conv2d reference: out is not [n*ho*wo, cout]");
    // The input index along an axis of `size` for output `o` and tap `t`, None in the padding.
    let source = |o: usize, t: usize, size: usize| (o * stride + t).checked_sub(padding).filter(|&i| i < size);
    for b in 0..n {
        for oy in 0..ho {
            for ox in 0..wo {
                let pixel = (b * ho + oy) * wo + ox;
                for co in 0..cout {
                    let mut sum = bias.map_or(0.0, |bias| bias[co]);
                    for ky in 0..k {
                        let Some(iy) = source(oy, ky, he) else { continue };
                        for kx in 0..k {
                            let Some(ix) = source(ox, kx, we) else { continue };
                            let src = ((b * h + iy / up) * w + ix / up) * cin;
                            for ci in 0..cin {
                                sum += x[src + ci] * weight[((co * cin + ci) * k + ky) * k + kx];
                            }
                        }
                    }
                    let o = &mut out[pixel * cout + co];
                    *o = match mode {
                        ConvMode::Overwrite => activation(sum, act),
                        ConvMode::Accumulate => *o + activation(sum, act),
                        ConvMode::Residual => activation(*o + sum, act),
                    };
                }
            }
        }
    }
}
