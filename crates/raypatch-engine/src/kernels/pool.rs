//! Max pooling on NHWC images (`shaders/pool.wgsl`): PyTorch's `nn.MaxPool2d(kernel, stride, padding)`
//! (ResNet's 3×3 stride-2 padding-1 pool after the stem).

use crate::kernels::{Window, POOL};
use crate::plan::{grid, Access, Op, PlanBuilder, View};
use crate::tensor::padded_cols;

params! {
    /// The uniform of `shaders/pool.wgsl`.
    PoolParams {
        h: u32,
        w: u32,
        /// ld(c) / 4: vec4s per row of x and out.
        c4: u32,
        ho: u32,
        wo: u32,
        /// The window: K × K taps, stride, padding.
        k: u32,
        stride: u32,
        pad: u32,
        /// n*ho*wo*c4: invocations that write.
        total: u32,
    }
}

/// A max pool's operands: see [`max_pool2d`].
#[derive(Clone, Copy, Debug)]
pub struct PoolArgs {
    /// `[n*h*w, c]` NHWC view.
    pub x: View,
    pub n: usize,
    pub h: usize,
    pub w: usize,
    /// `[n*ho*wo, c]` NHWC view.
    pub out: View,
    /// Kernel size, stride (>= 1) and padding (at most kernel / 2, as PyTorch requires).
    pub window: Window,
}

/// The output size `(ho, wo)` of a pool with `window` over an `h × w` image: PyTorch's
/// `floor((h + 2·padding − k) / stride) + 1` (`ceil_mode=False`); `None` when the window does not fit.
pub fn pool_output_size(h: usize, w: usize, window: Window) -> Option<(usize, usize)> {
    Some((window.output(h)?, window.output(w)?))
}

/// Max pooling of an NHWC image batch x: [n*h*w, c] -> out: [n*ho*wo, c] as PyTorch's
/// `F.max_pool2d(x, kernel, stride, padding)` (dilation 1, `ceil_mode=False`): the padding is −∞, so each
/// output is the maximum of the input pixels its window covers. Any `c >= 1`; the padding columns of `out`
/// are written with zeros. `out` must not overlap `x`. No multiply-adds.
pub fn max_pool2d(plan: &mut PlanBuilder, label: &str, args: PoolArgs) {
    let PoolArgs { x, n, h, w, out, window } = args;
    if plan.failed() {
        return; // a tensor is too large to index: the plan will not be built
    }
    let Window { kernel, stride, padding } = window;
    let c = plan.cols(x.id);
    assert!(n > 0 && h > 0 && w > 0, "{label}: empty image");
    assert!(kernel > 0 && stride > 0, "{label}: kernel {kernel} and stride {stride} must be at least 1");
    assert!(
        2 * padding <= kernel,
        "{label}: padding {padding} is more than half the kernel {kernel} (PyTorch refuses it)"
    );
    assert_eq!(x.rows, n * h * w, "{label}: x has {} rows, not n*h*w = {n}*{h}*{w}", x.rows);
    let Some((ho, wo)) = pool_output_size(h, w, window) else {
        panic!("{label}: a {kernel}x{kernel} window with padding {padding} does not fit a {h}x{w} image");
    };
    assert_eq!(out.rows, n * ho * wo, "{label}: out has {} rows, not n*ho*wo = {n}*{ho}*{wo}", out.rows);
    assert_eq!(plan.cols(out.id), c, "{label}: out has {} columns, x has {c}", plan.cols(out.id));
    let c4 = padded_cols(c) / 4;
    let total = n * ho * wo * c4;
    let params = PoolParams {
        h: h as u32,
        w: w as u32,
        c4: c4 as u32,
        ho: ho as u32,
        wo: wo as u32,
        k: kernel as u32,
        stride: stride as u32,
        pad: padding as u32,
        total: total as u32,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &POOL,
        entry: "max_pool2d",
        params: params.words(),
        bindings: vec![(x, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid(total.div_ceil(64)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
