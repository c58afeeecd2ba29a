//! Resizes of NHWC images (`shaders/resize.wgsl`), matching PyTorch's `F.interpolate` with `antialias=False`:
//! bilinear with `align_corners=False` (the Ray-Patch patch rays, made by torchvision's `Resize` of the
//! full-resolution ray grid, and the decoder's 2× rgb skips) and nearest (the official decoder's resize of
//! its output to `h_out × w_out`).

use crate::kernels::RESIZE;
use crate::plan::{grid, Access, Op, PlanBuilder, View};
use crate::tensor::padded_cols;

/// Checks the shapes and records one resize op.
#[allow(clippy::too_many_arguments)]
fn resize(
    plan: &mut PlanBuilder,
    label: &str,
    entry: &'static str,
    x: View,
    n: usize,
    (hi, wi): (usize, usize),
    out: View,
    (ho, wo): (usize, usize),
    accumulate: bool,
) {
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
    let scale = |i: usize, o: usize| (i as f32 / o as f32).to_bits();
    plan.push(Op {
        label: label.to_string(),
        shader: &RESIZE,
        entry,
        params: vec![
            hi as u32,
            wi as u32,
            ho as u32,
            wo as u32,
            c4 as u32,
            total as u32,
            scale(hi, ho),
            scale(wi, wo),
            accumulate as u32,
        ],
        bindings: vec![(x, Access::Read), (out, if accumulate { Access::ReadWrite } else { Access::Write })],
        workgroups: grid(total.div_ceil(64)),
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
#[allow(clippy::too_many_arguments)]
pub fn bilinear(
    plan: &mut PlanBuilder,
    label: &str,
    x: View,
    n: usize,
    hi: usize,
    wi: usize,
    out: View,
    ho: usize,
    wo: usize,
    accumulate: bool,
) {
    resize(plan, label, "bilinear", x, n, (hi, wi), out, (ho, wo), accumulate);
}

/// Nearest resize as PyTorch mode='nearest': src = min(floor(dst · (in/out as f32)), in − 1).
///
/// Same layouts as [`bilinear`]; `out` is overwritten, padding columns included.
#[allow(clippy::too_many_arguments)]
pub fn nearest(
    plan: &mut PlanBuilder,
    label: &str,
    x: View,
    n: usize,
    hi: usize,
    wi: usize,
    out: View,
    ho: usize,
    wo: usize,
) {
    resize(plan, label, "nearest", x, n, (hi, wi), out, (ho, wo), false);
}
