//! Float64 reference of the 3×3 convolution (PyTorch `nn.Conv2d(cin, cout, 3, stride, padding=1)`, optionally
//! preceded by `nn.Upsample(scale_factor=2, mode='nearest')`) with a fused activation, on NHWC images.

use crate::kernels::Activation;
use crate::reference::activation;

/// `act(conv3x3(up(x), weight) + bias) + residual`, zero padding 1, stride `stride`.
///
/// `x` is NHWC `[n*h*w, cin]`; `weight` is PyTorch's `[cout, cin, 3, 3]`; `bias` is `[cout]`; `residual`, when
/// given, is the `[n*ho*wo, cout]` tensor the result is added to. With `upsample_input` the convolution runs
/// on the 2× nearest upsampling of `x` (a `2h × 2w` image whose pixel `(y, x)` is `x[y / 2, x / 2]`).
/// Returns `[n*ho*wo, cout]` with `ho = (h' - 1) / stride + 1`, `h'` the height the convolution sees.
#[allow(clippy::too_many_arguments)]
pub fn conv3x3(
    x: &[f64],
    n: usize,
    h: usize,
    w: usize,
    cin: usize,
    weight: &[f64],
    bias: Option<&[f64]>,
    cout: usize,
    stride: usize,
    upsample_input: bool,
    act: Activation,
    residual: Option<&[f64]>,
) -> Vec<f64> {
    assert_eq!(x.len(), n * h * w * cin, "conv3x3 reference: x is not [n*h*w, cin]");
    assert_eq!(weight.len(), cout * cin * 9, "conv3x3 reference: weight is not [cout, cin, 3, 3]");
    let up = if upsample_input { 2 } else { 1 };
    let (he, we) = (h * up, w * up);
    let (ho, wo) = ((he - 1) / stride + 1, (we - 1) / stride + 1);
    let mut out = vec![0.0; n * ho * wo * cout];
    if let Some(r) = residual {
        assert_eq!(r.len(), out.len(), "conv3x3 reference: residual is not [n*ho*wo, cout]");
    }
    for b in 0..n {
        for oy in 0..ho {
            for ox in 0..wo {
                let pixel = (b * ho + oy) * wo + ox;
                for co in 0..cout {
                    let mut sum = bias.map_or(0.0, |bias| bias[co]);
                    for ky in 0..3 {
                        // Input row in the (upsampled) image, with padding 1.
                        let Some(iy) = (oy * stride + ky).checked_sub(1).filter(|&iy| iy < he) else {
                            continue;
                        };
                        for kx in 0..3 {
                            let Some(ix) = (ox * stride + kx).checked_sub(1).filter(|&ix| ix < we) else {
                                continue;
                            };
                            let src = ((b * h + iy / up) * w + ix / up) * cin;
                            for ci in 0..cin {
                                sum += x[src + ci] * weight[((co * cin + ci) * 3 + ky) * 3 + kx];
                            }
                        }
                    }
                    let i = pixel * cout + co;
                    out[i] = activation(sum, act) + residual.map_or(0.0, |r| r[i]);
                }
            }
        }
    }
    out
}
