//! Each op records its multiply-adds: `m·n·k` for a linear layer, `n·ho·wo·cout·k²·cin` for a k×k
//! convolution, `2·nq·nkv·dim_head·heads` for attention, `rows·n·cols` for a row mix, none for the
//! elementwise kernels (maps, softmax, normalisation, concatenation, GRU gates) and max pooling; plans sum
//! them.

use raypatch_engine::kernels::attention::{attention, AttentionArgs};
use raypatch_engine::kernels::concat::concat_columns;
use raypatch_engine::kernels::conv::conv2d;
use raypatch_engine::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
use raypatch_engine::kernels::gru::{gru_cell, GruArgs};
use raypatch_engine::kernels::matmul::{linear, LinearArgs};
use raypatch_engine::kernels::mix::{mix_rows, MixArgs};
use raypatch_engine::kernels::pool::{max_pool2d, PoolArgs};
use raypatch_engine::kernels::softmax::{normalize_rows, softmax, Axis, SoftmaxArgs};
use raypatch_engine::kernels::{Activation, Window};
use raypatch_engine::kernels::{Conv2dArgs, ConvMode};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::padded_cols;

use crate::common::*;

#[test]
fn multiply_adds_are_counted() {
    let mut plan = PlanBuilder::new();

    // Linear: x [5, 3] · wᵀ ([7, 3]) → [5, 7]: 5·7·3 = 105.
    let x = plan.input("x", 5, 3);
    let weight = plan.input("w", 7, 3);
    let bias = Some(plan.input("b", 1, 7));
    let y = plan.transient("y", 5, 7);
    let (xv, yv) = (plan.all(x), plan.all(y));
    let act = Activation::Relu;
    linear(&mut plan, "linear", LinearArgs { x: xv, weight, bias, out: yv, act, accumulate: false, norm: None });
    assert_eq!(plan.multiply_adds(), 105);

    // Conv: 2 images of 4×6 with cin = 3, stride 2 → 2×3, cout = 5: 2·2·3·5·9·3 = 1620.
    let (n, h, w, cin, cout) = (2, 4, 6, 3, 5);
    let image = plan.input("image", n * h * w, cin);
    let weight = plan.input("conv.w", cout, 9 * padded_cols(cin));
    let conv_out = plan.transient("conv", n * 2 * 3, cout);
    let (x, out) = (plan.all(image), plan.all(conv_out));
    let (window, upsample_input, act, mode) = (Window::new(3, 2, 1), false, Activation::None, ConvMode::Overwrite);
    let bias = None;
    let args = Conv2dArgs { x, n, h, w, cin, weight, bias, out, cout, window, upsample_input, act, mode };
    conv2d(&mut plan, "conv", args);
    assert_eq!(plan.multiply_adds(), 105 + 1620);

    // A 7×7 stride-2 padding-3 conv of the same images, accumulated into the same output (2×3 too): k² = 49
    // taps, 2·2·3·5·49·3 = 8820 (taps in the padding count: the kernel multiplies zeros there).
    let weight7 = plan.input("conv7.w", cout, 49 * padded_cols(cin));
    let (x, out) = (plan.all(image), plan.all(conv_out));
    let (window, mode) = (Window::new(7, 2, 3), ConvMode::Accumulate);
    let args = Conv2dArgs { x, n, h, w, cin, weight: weight7, bias, out, cout, window, upsample_input, act, mode };
    conv2d(&mut plan, "conv7", args);
    assert_eq!(plan.multiply_adds(), 105 + 1620 + 8820);

    // A max pool (2×3 → 1×2) counts nothing.
    let pooled = plan.output("pooled", n * 2, cout);
    let (x, out) = (plan.all(conv_out), plan.all(pooled));
    max_pool2d(&mut plan, "pool", PoolArgs { x, n, h: 2, w: 3, out, window: Window::new(3, 2, 1) });
    assert_eq!(plan.multiply_adds(), 105 + 1620 + 8820);

    // Attention: 5 queries, 5 keys, 2 heads of 4: 2·5·5·4·2 = 400 (qᵀk and the weighted values).
    let qkv = plan.input("qkv", 5, 24);
    let heads_out = plan.transient("attention", 5, 8);
    let (q, out) = (plan.all(qkv), plan.all(heads_out));
    let (k, v) = (q, q);
    let args = AttentionArgs { q, q_col: 0, k, k_col: 8, v, v_col: 16, out, heads: 2, dim_head: 4, scale: 0.5 };
    attention(&mut plan, "attention", args);
    assert_eq!(plan.multiply_adds(), 105 + 1620 + 8820 + 400);

    // Row mix: w [4, 5] · y [5, 7] → [4, 7]: 4·5·7 = 140.
    let mix_w = plan.input("mix.w", 4, 5);
    let mixed = plan.transient("mixed", 4, 7);
    let (w, out) = (plan.all(mix_w), plan.all(mixed));
    mix_rows(&mut plan, "mix", MixArgs { w, x: y, out });
    assert_eq!(plan.multiply_adds(), 105 + 1620 + 8820 + 400 + 140);

    // Elementwise ops count nothing.
    let copied = plan.output("copied", 5, 8);
    let (x, out) = (plan.all(heads_out), plan.all(copied));
    map_columns(&mut plan, "copy", MapColumnsArgs { x, col: 0, out, map: Map::Identity });
    let conv_copy = plan.output("conv_copy", n * 2 * 3, cout);
    let (x, out) = (plan.all(conv_out), plan.all(conv_copy));
    map_columns(&mut plan, "conv_copy", MapColumnsArgs { x, col: 0, out, map: Map::Identity });
    let y_copy = plan.output("y_copy", 5, 7);
    let (x, out) = (plan.all(y), plan.all(y_copy));
    map_columns(&mut plan, "y_copy", MapColumnsArgs { x, col: 0, out, map: Map::Sigmoid });
    let (attn, weights) = (plan.transient("attn", 4, 7), plan.output("weights", 4, 7));
    let (x, a, out) = (plan.all(mixed), plan.all(attn), plan.all(weights));
    softmax(&mut plan, "softmax", SoftmaxArgs { x, out: a, axis: Axis::Columns, scale: 0.5, eps: 1e-8 });
    normalize_rows(&mut plan, "normalize", a, out);
    let joined = plan.output("joined", 5, 15);
    let (a, b, out) = (plan.all(y), plan.all(heads_out), plan.all(joined));
    concat_columns(&mut plan, "concat", a, b, out);
    let (gates, state, next) = (plan.input("gates", 5, 15), plan.input("state", 5, 5), plan.output("next", 5, 5));
    let (gates, h, out) = (plan.all(gates), plan.all(state), plan.all(next));
    gru_cell(&mut plan, "gru", GruArgs { gi: gates, gh: gates, h, out });
    assert_eq!(plan.multiply_adds(), 11085);

    assert_eq!(run(plan).multiply_adds(), 11085, "the built plan keeps the count");
}
