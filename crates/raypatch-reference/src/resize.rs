//! Float64 references of PyTorch's image resizes (`F.interpolate` with `mode='bilinear', align_corners=False,
//! antialias=False` and `mode='nearest'`) on NHWC images. Source indices and weights are computed in f32
//! exactly as PyTorch does (they decide which pixels are read); the interpolation itself runs in f64.

/// PyTorch's `align_corners=False` linear source of output index `dst`: the two input indices and the
/// weight λ of the second (`area_pixel_compute_source_index` and `guard_index_and_lambda`). λ is an f32
/// value (computed in f32 as PyTorch does), returned exactly as f64.
pub fn linear_source(dst: usize, in_size: usize, out_size: usize) -> (usize, usize, f64) {
    let scale = in_size as f32 / out_size as f32;
    let src = (scale * (dst as f32 + 0.5) - 0.5).max(0.0);
    let i0 = (src.floor() as usize).min(in_size - 1);
    let lambda = (src - i0 as f32).clamp(0.0, 1.0);
    (i0, (i0 + 1).min(in_size - 1), f64::from(lambda))
}

/// PyTorch's `mode='nearest'` source of output index `dst`: `min(floor(dst · in/out), in − 1)`.
fn nearest_source(dst: usize, in_size: usize, out_size: usize) -> usize {
    let scale = in_size as f32 / out_size as f32;
    ((dst as f32 * scale).floor() as usize).min(in_size - 1)
}

/// Bilinear resize of `x`, NHWC `[n*hi*wi, c]`, to `[n*ho*wo, c]`.
pub fn bilinear(x: &[f64], n: usize, hi: usize, wi: usize, c: usize, ho: usize, wo: usize) -> Vec<f64> {
    assert_eq!(x.len(), n * hi * wi * c, "bilinear reference: x is not [n*hi*wi, c]");
    let at = |b: usize, y: usize, xx: usize, ch: usize| x[((b * hi + y) * wi + xx) * c + ch];
    let mut out = Vec::with_capacity(n * ho * wo * c);
    for b in 0..n {
        for oy in 0..ho {
            let (y0, y1, ly) = linear_source(oy, hi, ho);
            for ox in 0..wo {
                let (x0, x1, lx) = linear_source(ox, wi, wo);
                for ch in 0..c {
                    let top = (1.0 - lx) * at(b, y0, x0, ch) + lx * at(b, y0, x1, ch);
                    let bottom = (1.0 - lx) * at(b, y1, x0, ch) + lx * at(b, y1, x1, ch);
                    out.push((1.0 - ly) * top + ly * bottom);
                }
            }
        }
    }
    out
}

/// Nearest resize of `x`, NHWC `[n*hi*wi, c]`, to `[n*ho*wo, c]`.
pub fn nearest(x: &[f64], n: usize, hi: usize, wi: usize, c: usize, ho: usize, wo: usize) -> Vec<f64> {
    assert_eq!(x.len(), n * hi * wi * c, "nearest reference: x is not [n*hi*wi, c]");
    let mut out = Vec::with_capacity(n * ho * wo * c);
    for b in 0..n {
        for oy in 0..ho {
            let y = nearest_source(oy, hi, ho);
            for ox in 0..wo {
                let src = ((b * hi + y) * wi + nearest_source(ox, wi, wo)) * c;
                out.extend_from_slice(&x[src..src + c]);
            }
        }
    }
    out
}
