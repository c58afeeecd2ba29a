//! Ray-Patch querying in float64 (`models/ray_patch.rs`), shared by every family: the patch rays and the
//! `RayPatchDecoder`'s conv decoder.

use raypatch_model::TargetViews;

use super::{f64s, leaky_relu, Argument, Conv, Reader};
use crate::kernels::Activation;
use crate::models::ray_patch::RayPatchDecoder;
use crate::reference::resize::{bilinear, linear_source};

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
            skip = to_rgb.apply(&x, (views, h, w), 1, false, Activation::None, Some(&skip));
            if i + 1 < self.blocks.len() {
                skip = bilinear(&skip, views, h, w, channels, 2 * h, 2 * w);
            }
        }
        skip
    }
}

/// The patch rays `[views·ph·pw, 3]` of full-resolution target rays, bilinearly downsampled as the official
/// loader makes them: in f32 with [`Argument::RoundedToF32`] (PyTorch's float32 operation order), in f64
/// otherwise.
pub(super) fn patch_rays(targets: &TargetViews, ph: usize, pw: usize, argument: Argument) -> Vec<f64> {
    let (views, rh, rw) = (targets.count, targets.rays_height, targets.rays_width);
    match argument {
        Argument::RoundedToF32 => f64s(&patch_rays_f32(&targets.rays, views, rh, rw, ph, pw)),
        Argument::Float64 => bilinear(&f64s(&targets.rays), views, rh, rw, 3, ph, pw),
    }
}

/// PyTorch's float32 bilinear resize of NHWC rays `[n·hi·wi, 3]` to `[n·ho·wo, 3]`, in its channels-last
/// operation order `((x00·w00 + x01·w01) + x10·w10) + x11·w11` (weights multiplied first), as the engine's
/// patch rays compute it: with k a power of two the weights are exact and the result is PyTorch's, bit for bit.
fn patch_rays_f32(rays: &[f32], n: usize, hi: usize, wi: usize, ho: usize, wo: usize) -> Vec<f32> {
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
