//! Resizes of NHWC images (`shaders/resize.wgsl`), matching PyTorch's `F.interpolate` with `antialias=False`:
//! bilinear with `align_corners=False` (the Ray-Patch patch rays, made by torchvision's `Resize` of the
//! full-resolution ray grid, and the decoder's 2× rgb skips) and nearest (the official decoder's resize of
//! its output to `h_out × w_out`).

use crate::kernels::RESIZE;
use crate::plan::{grid, Access, Op, PlanBuilder, View};
use crate::tensor::padded_cols;

params! {
    /// The uniform of `shaders/resize.wgsl`.
    ResizeParams {
        hi: u32,
        wi: u32,
        ho: u32,
        wo: u32,
        /// ld(c) / 4: vec4s per row of x and out.
        c4: u32,
        /// n*ho*wo*c4: invocations that write.
        total: u32,
        scale_h: f32,
        scale_w: f32,
        /// bilinear only: out += result instead of out = result.
        accumulate: u32,
    }
}

/// A resize's operands: see [`bilinear`] and [`nearest`]. Sizes are `(height, width)`.
#[derive(Clone, Copy, Debug)]
pub struct ResizeArgs {
    /// `[n*from.0*from.1, c]` NHWC view.
    pub x: View,
    pub n: usize,
    pub from: (usize, usize),
    /// `[n*to.0*to.1, c]` NHWC view.
    pub out: View,
    pub to: (usize, usize),
    /// `out += ...` instead of `out = ...` (bilinear only).
    pub accumulate: bool,
}

/// Checks the shapes and records one resize op (no multiply-adds: resizes are not multiply-add work worth
/// counting).
fn resize(plan: &mut PlanBuilder, label: &str, entry: &'static str, args: ResizeArgs) {
    let ResizeArgs { x, n, from: (hi, wi), out, to: (ho, wo), accumulate } = args;
    if plan.failed() {
        return; // a tensor is too large to index: the plan will not be built
    }
    let c = plan.cols(x.id);
    assert!(hi > 0 && wi > 0 && ho > 0 && wo > 0, "{label}: empty image ({hi}x{wi} -> {ho}x{wo})");
    assert_eq!(x.rows, n * hi * wi, "{label}: x has {} rows, not n*hi*wi = {n}*{hi}*{wi}", x.rows);
    assert_eq!(out.rows, n * ho * wo, "{label}: out has {} rows, not n*ho*wo = {n}*{ho}*{wo}", out.rows);
    assert_eq!(plan.cols(out.id), c, "{label}: out has {} columns, x has {c}", plan.cols(out.id));
    let c4 = padded_cols(c) / 4;
    let total = n * ho * wo * c4;
    // PyTorch's scale: input size over output size, as f32 (for scale_factor = 2 this is 1/2, the same value).
    let scale = |i: usize, o: usize| i as f32 / o as f32;
    let params = ResizeParams {
        hi: hi as u32,
        wi: wi as u32,
        ho: ho as u32,
        wo: wo as u32,
        c4: c4 as u32,
        total: total as u32,
        scale_h: scale(hi, ho),
        scale_w: scale(wi, wo),
        accumulate: accumulate as u32,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &RESIZE,
        entry,
        params: params.words(),
        bindings: vec![(x, Access::Read), (out, if accumulate { Access::ReadWrite } else { Access::Write })],
        textures: Vec::new(),
        workgroups: grid(total.div_ceil(64)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}

/// Bilinear resize of an NHWC image batch x: [n*hi*wi, c] -> out: [n*ho*wo, c] exactly as PyTorch
/// F.interpolate(mode='bilinear', align_corners=False, antialias=False): src = max(scale·(dst+0.5) − 0.5, 0) with
/// scale = in/out as f32, i0 = floor(src), i1 = min(i0+1, in−1), λ = src − i0, and the output
/// ((x00·w00 + x01·w01) + x10·w10) + x11·w11 with w00 = h0λ·w0λ etc. (PyTorch's channels-last evaluation
/// order, bit-exact for the patch rays). When `accumulate`, out += result.
///
/// `x` and `out` are views of tensors with the same number of columns `c` (any `c >= 1`); the padding columns
/// of `out` are written with zeros (or stay zero when accumulating). `out` must not overlap `x`.
/// `from = (hi, wi)`, `to = (ho, wo)`.
pub fn bilinear(plan: &mut PlanBuilder, label: &str, args: ResizeArgs) {
    resize(plan, label, "bilinear", args);
}

/// Nearest resize as PyTorch mode='nearest': src = min(floor(dst · (in/out as f32)), in − 1).
///
/// Same layouts as [`bilinear`]; `out` is overwritten, padding columns included: `args.accumulate` must
/// be false.
pub fn nearest(plan: &mut PlanBuilder, label: &str, args: ResizeArgs) {
    assert!(!args.accumulate, "{label}: nearest resize cannot accumulate");
    resize(plan, label, "nearest", args);
}
