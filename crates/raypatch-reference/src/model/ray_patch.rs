//! Ray-Patch querying in float64 (`models/ray_patch.rs`), shared by every family: the patch rays and the
//! `RayPatchDecoder`'s conv decoder; with the bilinear resizes in a tensor's precision that DeFiNe's encoder
//! (its rays, its feature maps) and OSRT's segmentation share with the patch rays.

use raypatch_model::TargetViews;

use super::{f64s, leaky_relu, Argument, Conv, Reader};
use crate::resize::{bilinear, linear_source};
use raypatch_engine::kernels::Activation;
use raypatch_engine::kernels::ConvMode;
use raypatch_engine::models::ray_patch::RayPatchDecoder;

/// LeakyReLU slope of the conv decoder's feature convs as float64 torch has it (see `OUT_MLP_SLOPE`).
const CONV_DECODER_SLOPE: f64 = 0.2;

/// `RayPatchDecoder.conv_decoder`: conv_0, then per block (feature conv, rgb conv).
pub(super) struct ConvDecoder {
    conv_0: Conv,
    blocks: Vec<(Conv, Conv)>,
}

impl Reader<'_> {
    pub(super) fn ray_patch(&self, rp: &Option<RayPatchDecoder>) -> Option<ConvDecoder> {
        rp.as_ref().map(|rp| ConvDecoder {
            conv_0: self.conv(&rp.conv_0),
            blocks: rp.blocks.iter().map(|b| (self.conv(&b.features), self.conv(&b.to_rgb))).collect(),
        })
    }
}

impl ConvDecoder {
    /// The image `[views·(k·ph)·(k·pw), channels]` before the sigmoid from the patch features, an NHWC image
    /// `[views·ph·pw, conv_features]`.
    pub(super) fn forward(&self, features: Vec<f64>, views: usize, ph: usize, pw: usize, channels: usize) -> Vec<f64> {
        // conv_0's output, bilinearly upsampled, is the first rgb skip; each block adds its rgb conv to the
        // skip, which is upsampled again for the next block.
        let (mut h, mut w) = (ph, pw);
        let first = self.conv_0.apply(&features, (views, h, w), 1, false, Activation::None, None);
        let mut skip = bilinear(&first, views, h, w, channels, 2 * h, 2 * w);
        let mut x = features;
        for (i, (feature_conv, to_rgb)) in self.blocks.iter().enumerate() {
            x = leaky_relu(feature_conv.apply(&x, (views, h, w), 1, true, Activation::None, None), CONV_DECODER_SLOPE);
            (h, w) = (2 * h, 2 * w);
            skip = to_rgb.apply(&x, (views, h, w), 1, false, Activation::None, Some((ConvMode::Accumulate, &skip)));
            if i + 1 < self.blocks.len() {
                skip = bilinear(&skip, views, h, w, channels, 2 * h, 2 * w);
            }
        }
        skip
    }
}

/// The patch rays `[views·ph·pw, 3]` of full-resolution target rays, bilinearly downsampled as the official
/// loader makes them ([`resized_rays`]).
pub(super) fn patch_rays(targets: &TargetViews, ph: usize, pw: usize, argument: Argument) -> Vec<f64> {
    let (views, rh, rw) = (targets.count, targets.rays_height, targets.rays_width);
    resized_rays(&targets.ray_values(), views, (rh, rw), (ph, pw), argument)
}

/// Ray grids `[n·hi·wi, 3]` bilinearly resized to `ho × wo` as PyTorch resizes them (the official loader's
/// patch rays, DeFiNe's encoder rays at H/4 × W/4): in f32 with [`Argument::RoundedToF32`] (PyTorch's
/// float32 operation order), in f64 otherwise.
pub(super) fn resized_rays(
    rays: &[f32],
    n: usize,
    (hi, wi): (usize, usize),
    (ho, wo): (usize, usize),
    argument: Argument,
) -> Vec<f64> {
    match argument {
        Argument::RoundedToF32 => f64s(&resized_rays_f32(rays, n, hi, wi, ho, wo)),
        Argument::Float64 => resize_bilinear(&f64s(rays), n, (hi, wi), 3, (ho, wo), argument),
    }
}

/// PyTorch's bilinear resize (`align_corners=False`) of an NHWC image `[n·hi·wi, c]` to `ho × wo`, with its
/// source indices and weights computed in the tensor's precision: f32 as float32 torch and the engine have
/// them with [`Argument::RoundedToF32`] (`reference::resize::bilinear`), f64 as float64 torch has them
/// otherwise (`area_pixel_compute_source_index` in the scalar type). The two agree for power-of-two ratios,
/// and differ by ~1e-8 relatively for others (DeFiNe's 15×22 ← 8×11 feature maps).
pub(super) fn resize_bilinear(
    x: &[f64],
    n: usize,
    (hi, wi): (usize, usize),
    c: usize,
    (ho, wo): (usize, usize),
    argument: Argument,
) -> Vec<f64> {
    if argument == Argument::RoundedToF32 {
        return bilinear(x, n, hi, wi, c, ho, wo);
    }
    assert_eq!(x.len(), n * hi * wi * c, "bilinear reference: x is not [n*hi*wi, c]");
    let source = |dst: usize, size: usize, out: usize| {
        let src = (size as f64 / out as f64 * (dst as f64 + 0.5) - 0.5).max(0.0);
        let i0 = (src.floor() as usize).min(size - 1);
        (i0, (i0 + 1).min(size - 1), (src - i0 as f64).clamp(0.0, 1.0))
    };
    let mut out = Vec::with_capacity(n * ho * wo * c);
    for b in 0..n {
        for oy in 0..ho {
            let (y0, y1, ly) = source(oy, hi, ho);
            for ox in 0..wo {
                let (x0, x1, lx) = source(ox, wi, wo);
                let at = |y: usize, xx: usize, ch: usize| x[((b * hi + y) * wi + xx) * c + ch];
                for ch in 0..c {
                    let top = (1.0 - lx) * at(y0, x0, ch) + lx * at(y0, x1, ch);
                    let bottom = (1.0 - lx) * at(y1, x0, ch) + lx * at(y1, x1, ch);
                    out.push((1.0 - ly) * top + ly * bottom);
                }
            }
        }
    }
    out
}

/// PyTorch's float32 bilinear resize of NHWC rays `[n·hi·wi, 3]` to `[n·ho·wo, 3]`, in its channels-last
/// operation order `((x00·w00 + x01·w01) + x10·w10) + x11·w11` (weights multiplied first), as the engine's
/// bilinear kernel computes it: with a power-of-two ratio (k, DeFiNe's 4) the weights are exact and the
/// result is PyTorch's, bit for bit.
fn resized_rays_f32(rays: &[f32], n: usize, hi: usize, wi: usize, ho: usize, wo: usize) -> Vec<f32> {
    let at = |b: usize, y: usize, x: usize, c: usize| rays[((b * hi + y) * wi + x) * 3 + c];
    let mut out = Vec::with_capacity(n * ho * wo * 3);
    for b in 0..n {
        for oy in 0..ho {
            let (y0, y1, ly) = linear_source(oy, hi, ho);
            let (h1, h0) = (ly as f32, 1.0 - ly as f32);
            for ox in 0..wo {
                let (x0, x1, lx) = linear_source(ox, wi, wo);
                let (w1, w0) = (lx as f32, 1.0 - lx as f32);
                for c in 0..3 {
                    let v = at(b, y0, x0, c) * (h0 * w0) + at(b, y0, x1, c) * (h0 * w1);
                    let v = v + at(b, y1, x0, c) * (h1 * w0);
                    out.push(v + at(b, y1, x1, c) * (h1 * w1));
                }
            }
        }
    }
    out
}
