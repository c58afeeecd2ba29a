//! Max pooling against the float64 reference.

use raypatch_engine::kernels::pool::{max_pool2d, pool_output_size, PoolArgs};
use raypatch_engine::kernels::Window;
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::pool as reference;

use crate::common::*;
use crate::conv::Placed;

/// Pools random data `[n*h*w, c]` on the GPU and checks it against the reference: a max copies an input
/// value, so the result must be exact.
fn check(rng: &mut Rng, n: usize, h: usize, w: usize, c: usize, window: Window) {
    let what = format!("max_pool2d {n}x{h}x{w}x{c} {window:?}");
    let (ho, wo) = pool_output_size(h, w, window).expect("the case's window fits");
    // Negative values too: the padding must never win (it is −∞, not 0).
    let x = rng.vec_f32(n * h * w * c, -2.0, 1.0);
    let xp = Placed::new(rng, "x", &x, c, 0.0);
    let op = Placed::new(rng, "out", &vec![0.0; n * ho * wo * c], c, f32::NAN);
    let mut plan = PlanBuilder::new();
    let (xv, ov) = (xp.view(&mut plan, "x"), op.view(&mut plan, "out"));
    max_pool2d(&mut plan, "pool", PoolArgs { x: xv, n, h, w, out: ov, window });
    run(plan);
    let got = op.read_view(&what);
    assert_close(&what, &got, &reference::max_pool2d(&to_f64(&x), (n, h, w), c, window), 0.0, 0.0);
}

#[test]
fn max_pool_resnet_3x3_stride2_pad1() {
    // ResNet's pool after the stem (64 channels), at even and odd sizes, and 1-pixel images.
    let mut rng = Rng::new(21);
    let window = Window::new(3, 2, 1);
    for (h, w, c) in [(60, 80, 64), (23, 31, 64), (1, 1, 5), (2, 3, 7), (5, 4, 1)] {
        check(&mut rng, 2, h, w, c, window);
    }
}

#[test]
fn max_pool_random_windows() {
    // Kernels 1..5, strides 1..3, paddings 0..k/2 (PyTorch's limit), channels not multiples of 4.
    let mut rng = Rng::new(22);
    for case in 0..40 {
        let kernel = 1 + case % 5;
        let stride = 1 + (case / 5) % 3;
        let padding = rng.range(0, kernel / 2);
        let least = kernel.saturating_sub(2 * padding).max(1);
        let (h, w) = (rng.range(least, least + 15), rng.range(least, least + 15));
        let (n, c) = (rng.range(1, 3), rng.range(1, 13));
        check(&mut rng, n, h, w, c, Window::new(kernel, stride, padding));
    }
}

#[test]
fn max_pool_many_workgroups() {
    // More than 65535 workgroups: the grid spills into y.
    let mut rng = Rng::new(23);
    let (h, w, c) = (512, 600, 64);
    let window = Window::new(2, 1, 0);
    let (ho, wo) = pool_output_size(h, w, window).unwrap();
    assert!((ho * wo * c / 4).div_ceil(64) > 65535);
    check(&mut rng, 1, h, w, c, window);
}
