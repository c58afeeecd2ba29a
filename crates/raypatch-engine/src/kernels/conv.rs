//! 3×3 convolutions on NHWC images (`shaders/conv.wgsl`): the SRT encoder's conv blocks (stride 1 and 2) and
//! the Ray-Patch decoder's upsample-then-conv layers, with BatchNorm folded into the weight and bias by the
//! model loader and the activation fused.

use crate::kernels::{Activation, CONV};
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, View};
use crate::tensor::padded_cols;

/// Output pixels per invocation, 64 apart in the flattened n*ho*wo order (`PX` in the shader).
const PIXELS_PER_INVOCATION: usize = 8;
/// Vec4s of output channels per invocation (`CV` in the shader).
const COUT_VEC4S_PER_INVOCATION: usize = 2;

/// Repacks a PyTorch conv weight [cout, cin, 3, 3] (row-major) into the kernel's layout, returned as a row-major
/// [cout, 9 * padded_cols(cin)] matrix: for each output channel, the 9 taps (ky, kx row-major), each a zero-padded
/// run of cin input channels. Upload it with Gpu::upload(label, cout, 9 * padded_cols(cin), &packed).
pub fn pack_conv3x3(weight: &[f32], cout: usize, cin: usize) -> Vec<f32> {
    assert_eq!(weight.len(), cout * cin * 9, "pack_conv3x3: weight has {} values, not cout*cin*9", weight.len());
    let ld = padded_cols(cin);
    let mut packed = vec![0.0; cout * 9 * ld];
    for co in 0..cout {
        for ci in 0..cin {
            for tap in 0..9 {
                packed[(co * 9 + tap) * ld + ci] = weight[(co * cin + ci) * 9 + tap];
            }
        }
    }
    packed
}

params! {
    /// The uniform of `shaders/conv.wgsl`.
    ConvParams {
        h: u32,
        w: u32,
        /// ld(cin) / 4: vec4s per row of x and per tap of w.
        cin4: u32,
        cout: u32,
        /// ld(cout) / 4: vec4s per row of out.
        cout4: u32,
        ho: u32,
        wo: u32,
        stride: u32,
        /// 1 when the input is upsampled 2× (nearest) before the convolution, else 0.
        up: u32,
        /// Activation code and slope ([`Activation::params`]).
        act: u32,
        slope: f32,
        has_bias: u32,
        accumulate: u32,
        /// n*ho*wo.
        npix: u32,
        /// ceil(cout4 / CV): channel tiles, the fastest-varying part of the group index.
        cout_tiles: u32,
        /// ceil(npix / (64 * PX)): pixel tiles.
        pixel_tiles: u32,
    }
}

/// A convolution's operands and options: see [`conv3x3`].
#[derive(Clone, Copy, Debug)]
pub struct Conv3x3Args {
    /// `[n*h*w, cin]` NHWC view.
    pub x: View,
    pub n: usize,
    pub h: usize,
    pub w: usize,
    pub cin: usize,
    /// [`pack_conv3x3`]'s `[cout, 9 * padded_cols(cin)]` matrix.
    pub weight: TensorId,
    /// `[1, cout]` tensor.
    pub bias: Option<TensorId>,
    /// `[n*ho*wo, cout]` NHWC view.
    pub out: View,
    pub cout: usize,
    /// 1 or 2.
    pub stride: usize,
    /// Upsample the input 2× (nearest) before the convolution.
    pub upsample_input: bool,
    pub act: Activation,
    /// `out += ...` instead of `out = ...`.
    pub accumulate: bool,
}

/// 3×3 convolution with zero padding 1 and stride 1 or 2, NHWC: x is [n*h*w, cin]. With `upsample_input` the input
/// is first upsampled 2× nearest (the conv sees a 2h×2w image; fuse it: read x at (y/2, x/2), never materialise it).
/// Output [n*ho*wo, cout] with ho = (h_eff - 1) / stride + 1 (h_eff = h or 2h). out = act(conv + bias), or
/// out += act(conv + bias) when `accumulate`.
///
/// `weight` is [`pack_conv3x3`]'s `[cout, 9 * padded_cols(cin)]` matrix, `bias` a `[1, cout]` tensor. `act` is
/// any [`Activation`]. The padding columns of `out` are written with zeros
/// (or stay zero when accumulating). `out` must not overlap `x`. Records `n·ho·wo·cout·9·cin` multiply-adds.
pub fn conv3x3(plan: &mut PlanBuilder, label: &str, args: Conv3x3Args) {
    let Conv3x3Args { x, n, h, w, cin, weight, bias, out, cout, stride, upsample_input, act, accumulate } = args;
    if plan.failed() {
        return; // a tensor is too large to index: the plan will not be built
    }
    assert!(n > 0 && h > 0 && w > 0 && cin > 0 && cout > 0, "{label}: empty convolution");
    assert!(stride == 1 || stride == 2, "{label}: stride {stride} is not 1 or 2");
    assert_eq!(x.rows, n * h * w, "{label}: x has {} rows, not n*h*w = {n}*{h}*{w}", x.rows);
    assert_eq!(plan.cols(x.id), cin, "{label}: x has {} columns, not cin = {cin}", plan.cols(x.id));
    let (wrows, wcols) = (plan.rows(weight), plan.cols(weight));
    assert!(
        wrows == cout && wcols == 9 * padded_cols(cin),
        "{label}: weight is [{wrows}, {wcols}], not the packed [cout, 9*ld(cin)] = [{cout}, {}]",
        9 * padded_cols(cin)
    );
    if let Some(b) = bias {
        let (brows, bcols) = (plan.rows(b), plan.cols(b));
        assert!(brows == 1 && bcols == cout, "{label}: bias is [{brows}, {bcols}], not [1, {cout}]");
    }
    let up = usize::from(upsample_input);
    let (ho, wo) = (((h << up) - 1) / stride + 1, ((w << up) - 1) / stride + 1);
    let npix = n * ho * wo;
    assert_eq!(out.rows, npix, "{label}: out has {} rows, not n*ho*wo = {n}*{ho}*{wo}", out.rows);
    assert_eq!(plan.cols(out.id), cout, "{label}: out has {} columns, not cout = {cout}", plan.cols(out.id));

    let cout4 = padded_cols(cout) / 4;
    let cout_tiles = cout4.div_ceil(COUT_VEC4S_PER_INVOCATION);
    let pixel_tiles = npix.div_ceil(64 * PIXELS_PER_INVOCATION);
    let (act_code, slope) = act.params();
    let params = ConvParams {
        h: h as u32,
        w: w as u32,
        cin4: (padded_cols(cin) / 4) as u32,
        cout: cout as u32,
        cout4: cout4 as u32,
        ho: ho as u32,
        wo: wo as u32,
        stride: stride as u32,
        up: up as u32,
        act: act_code,
        slope,
        has_bias: bias.is_some() as u32,
        accumulate: accumulate as u32,
        npix: npix as u32,
        cout_tiles: cout_tiles as u32,
        pixel_tiles: pixel_tiles as u32,
    };
    let weight_view = plan.all(weight);
    let bias_view = bias.map_or(weight_view, |b| plan.all(b));
    plan.push(Op {
        label: label.to_string(),
        shader: &CONV,
        entry: "conv3x3",
        params: params.words(),
        bindings: vec![
            (x, Access::Read),
            (weight_view, Access::Read),
            (bias_view, Access::Read),
            (out, if accumulate { Access::ReadWrite } else { Access::Write }),
        ],
        workgroups: grid(pixel_tiles * cout_tiles),
        multiply_adds: (npix as u64) * (cout as u64) * 9 * (cin as u64),
    });
}
