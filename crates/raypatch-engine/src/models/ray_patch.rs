//! Ray-Patch querying, shared by every family: one ray per k×k patch (`patch_rays`), and the
//! `RayPatchDecoder` (official `src/decoder.py`) that turns the patch features into the image: per 2× step,
//! nearest upsample → conv → BN → LeakyReLU(0.2) on the features, and an RGB conv added to the bilinearly
//! upsampled RGB skip. Also the region walk: which patches a region of the output depends on.

use raypatch_model::RayPatchConfig;

use super::{resize_into, resized};
use crate::error::Result;
use crate::graph::{Graph, ImageSize, Tensor};
use crate::kernels::resize::{bilinear, nearest};
use crate::kernels::Activation;
use crate::kernels::ConvMode;
use crate::nn::{Conv2d, ConvSpec, Vars};

/// LeakyReLU slope of the conv decoder's feature convs.
pub const CONV_DECODER_SLOPE: f32 = 0.2;

/// One 2× step: the feature conv (`conv_blocks.{i}.0.1`, BN at `.0.2`) and its RGB conv (`conv_blocks.{i}.1`).
pub struct UpBlock {
    pub features: Conv2d,
    pub to_rgb: Conv2d,
}

/// `RayPatchDecoder.conv_decoder`.
pub struct RayPatchDecoder {
    pub path: String,
    /// The first RGB skip, from the patch features.
    pub conv_0: Conv2d,
    pub blocks: Vec<UpBlock>,
}

impl RayPatchDecoder {
    pub fn new(vars: &Vars, c: &RayPatchConfig) -> Result<Self> {
        let blocks = (0..c.upsample)
            .map(|i| {
                let (cin, cout) = (c.conv_features >> i, c.conv_features >> (i + 1));
                let block = vars.pp("conv_blocks").pp(i);
                let bn = c.batch_norm.then(|| block.pp("0.2"));
                Ok(UpBlock {
                    features: Conv2d::new(&block.pp("0.1"), ConvSpec::new(cin, cout, 3, 1, 1).after_upsample(), bn)?,
                    to_rgb: Conv2d::new(&block.pp(1), ConvSpec::new(cout, c.out_dims, 3, 1, 1), None)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(RayPatchDecoder {
            path: vars.path().to_string(),
            conv_0: Conv2d::new(&vars.pp("conv_0"), ConvSpec::new(c.conv_features, c.out_dims, 3, 1, 1), None)?,
            blocks,
        })
    }

    /// Patch rays: the full-resolution rays bilinearly downsampled to the patch grid, not renormalised
    /// (torchvision Resize, as the official data loader makes them).
    pub fn patch_rays(&self, g: &mut Graph, rays: Tensor, patches: ImageSize) -> Tensor {
        resized(g, "patch_rays", rays, patches, bilinear)
    }

    /// The image `[views·H·W, channels]` before the sigmoid from the patch features (an image of the patch
    /// grid), nearest-resized to `size` (height, width) when k does not divide it (the official
    /// `F.interpolate(output, (h_out, w_out))`).
    pub fn forward(&self, g: &mut Graph, features: Tensor, size: (usize, usize)) -> Tensor {
        let first = self.conv_0.forward(g, features, Activation::None);
        let mut skip = self.upsample_skip(g, first, 0);
        let mut x = features;
        for (i, block) in self.blocks.iter().enumerate() {
            x = block.features.forward(g, x, Activation::LeakyRelu(CONV_DECODER_SLOPE));
            // x_out = conv_out(x) + skip, accumulated into the upsampled skip.
            block.to_rgb.forward_into(g, x, skip, Activation::None, ConvMode::Accumulate);
            if i + 1 < self.blocks.len() {
                skip = self.upsample_skip(g, skip, i + 1);
            }
        }
        let computed = skip.size();
        if (computed.h, computed.w) == size {
            return skip;
        }
        let to = ImageSize { h: size.0, w: size.1, ..computed };
        resized(g, &format!("{}.resize_out", self.path), skip, to, nearest)
    }

    /// The RGB skip bilinearly upsampled 2× (`skip.{i}`).
    fn upsample_skip(&self, g: &mut Graph, skip: Tensor, i: usize) -> Tensor {
        let size = skip.size();
        let to = ImageSize { h: 2 * size.h, w: 2 * size.w, ..size };
        resized(g, &format!("{}.skip.{i}", self.path), skip, to, bilinear)
    }

    /// The patches `first..=last` along an axis of `patches` patches whose features the output pixels
    /// `lo..=hi` depend on: a 3×3 conv reads one pixel further each side, and each 2× step (the nearest
    /// upsampling before a block's conv, the bilinear rgb skip) reads source pixels
    /// `floor((lo-1)/2) ..= floor((hi+1)/2)`. Reads past the image edge are padding in a full render too, so
    /// spans are clipped there. With these patches decoded, the pixels equal those of a full render.
    pub fn patch_span(&self, lo: usize, hi: usize, patches: usize) -> (usize, usize) {
        type Span = (isize, isize);
        let upsample = self.blocks.len();
        let clip = |(lo, hi): Span, level: usize| (lo.max(0), hi.min(((patches << level) - 1) as isize));
        let grow = |(lo, hi): Span| (lo - 1, hi + 1);
        let half = |(lo, hi): Span| ((lo - 1).div_euclid(2), (hi + 1).div_euclid(2));
        let hull = |a: Span, b: Span| (a.0.min(b.0), a.1.max(b.1));
        // At each level: the skip (rgb) pixels needed, and the feature pixels needed (`x` of the next block's
        // conv, and the input of this level's to-rgb conv, which writes the skip).
        let mut skip: Span = (lo as isize, hi as isize);
        let mut features = clip(grow(skip), upsample);
        for level in (0..upsample).rev() {
            skip = clip(half(skip), level);
            features = clip(hull(half(features), grow(skip)), level);
        }
        (features.0 as usize, features.1 as usize)
    }
}

/// The patches `first..=last` along an axis of `patches` patches of k pixels that a bilinear resize of the
/// patch grid to the pixels (`align_corners=False`, scale 1/k) reads for output pixels `lo..=hi`: source
/// `max((y + 0.5)/k - 0.5, 0)`, its floor and the next patch.
pub fn bilinear_patch_span(lo: usize, hi: usize, patches: usize, k: usize) -> (usize, usize) {
    // floor(max((2y + 1 - k) / 2k, 0)) in integers.
    let source = |y: usize| (2 * y + 1).saturating_sub(k) / (2 * k);
    (source(lo).min(patches - 1), (source(hi) + 1).min(patches - 1))
}

/// Values of the patch grid `x` (an image) bilinearly resized to `size` into the plan output `name` (the
/// official OSRT.decoder's `F.interpolate(..., mode="bilinear")` of the slot weights).
pub fn bilinear_output(g: &mut Graph, name: &str, x: Tensor, size: ImageSize) -> Tensor {
    let out = g.output(name, size.pixels(), x.cols);
    resize_into(g, name, x, out, size, bilinear);
    out
}
