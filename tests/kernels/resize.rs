//! Bilinear and nearest resizes against the float64 reference.

use raypatch_engine::kernels::resize::{bilinear, nearest, ResizeArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::resize as reference;

use crate::common::*;
use crate::conv::Placed;

/// Resizes random data `[n*hi*wi, c]` to `ho × wo` on the GPU and checks it against the reference.
#[allow(clippy::too_many_arguments)]
fn check(rng: &mut Rng, accumulate: bool, n: usize, hi: usize, wi: usize, c: usize, ho: usize, wo: usize) {
    let what = format!("bilinear (accumulate {accumulate}) {n}x{hi}x{wi}x{c} -> {ho}x{wo}");
    let x = rng.vec_f32(n * hi * wi * c, -1.0, 1.0);
    let init = rng.vec_f32(n * ho * wo * c, -1.0, 1.0);
    let xp = Placed::new(rng, "x", &x, c, 0.0);
    let op = Placed::new(rng, "out", &init, c, if accumulate { 0.0 } else { f32::NAN });

    let mut plan = PlanBuilder::new();
    let xv = xp.view(&mut plan, "x");
    let ov = op.view(&mut plan, "out");
    bilinear(&mut plan, "resize", ResizeArgs { x: xv, n, from: (hi, wi), out: ov, to: (ho, wo), accumulate });
    run(plan);
    let got = op.read_view(&what);

    let x = to_f64(&x);
    let mut expected = reference::bilinear(&x, n, hi, wi, c, ho, wo);
    if accumulate {
        expected.iter_mut().zip(&init).for_each(|(e, &i)| *e += f64::from(i));
    }
    // The same f32 source coordinates and λ as the reference, then a blend of
    // 4 values with |x| <= 1 (a few 2^-24 of rounding; 1.4e-7 measured on lavapipe). A driver may fuse
    // scale·(dst+0.5)−0.5 into an fma, moving λ by an ulp of the source coordinate (< 2^-17 for the sizes
    // here whose scale is not a power of two), which moves the result by up to 2·2^-17: allow 2e-5.
    assert_close(&what, &got, &expected, 2e-5, 0.0);
}

const CHANNELS: [usize; 3] = [1, 3, 5];

#[test]
fn bilinear_downsample_by_k() {
    // The patch-ray case: the full-resolution ray grid resized to [H/k, W/k], including sizes k does not divide.
    let mut rng = Rng::new(11);
    for (i, k) in [2, 4, 8, 16].into_iter().enumerate() {
        for c in CHANNELS {
            let (hi, wi) =
                if c == 3 { (k * rng.range(1, 4), k * rng.range(1, 5)) } else { (rng.range(k, 70), rng.range(k, 70)) };
            let n = rng.range(1, 3);
            check(&mut rng, i % 2 == 1, n, hi, wi, c, hi / k, wi / k);
        }
    }
    // The model's 120x160 grid at k = 8.
    check(&mut rng, false, 1, 120, 160, 3, 15, 20);
}

#[test]
fn bilinear_upsample_2x() {
    // The decoder's rgb skip: F.interpolate(scale_factor=2), accumulated into the next stage's output.
    let mut rng = Rng::new(12);
    for (i, c) in CHANNELS.into_iter().enumerate() {
        for accumulate in [false, true] {
            let (hi, wi, n) = (rng.range(1, 17) + i, rng.range(1, 17), rng.range(1, 3));
            check(&mut rng, accumulate, n, hi, wi, c, 2 * hi, 2 * wi);
        }
    }
}

#[test]
fn bilinear_upsample_non_integer() {
    // Up-scaling by factors that are not integers (PyTorch's `size=`, scale = in/out): 4x6 and 15x20 to
    // 32x48 (8×, and 2.13× by 2.4×), and the other way round of the axes.
    let mut rng = Rng::new(16);
    for (i, (hi, wi, ho, wo)) in
        [(4, 6, 32, 48), (15, 20, 32, 48), (6, 4, 48, 32), (20, 15, 48, 32), (7, 9, 32, 48)].into_iter().enumerate()
    {
        check(&mut rng, i % 2 == 1, 1 + i % 2, hi, wi, CHANNELS[i % 3], ho, wo);
    }
}

#[test]
fn bilinear_random_sizes() {
    // Arbitrary ratios in both directions, 1-pixel images, odd sizes.
    let mut rng = Rng::new(13);
    for case in 0..24 {
        let (hi, wi, ho, wo) = (rng.range(1, 25), rng.range(1, 25), rng.range(1, 25), rng.range(1, 25));
        let n = rng.range(1, 3);
        check(&mut rng, case % 2 == 1, n, hi, wi, CHANNELS[case % 3], ho, wo);
    }
}

#[test]
fn bilinear_many_workgroups() {
    // 4.3 million output pixels of one vec4 each: more than 65535 workgroups, so the grid spills into y.
    let mut rng = Rng::new(14);
    let (ho, wo): (usize, usize) = (1024, 4200);
    assert!((ho * wo).div_ceil(64) > 65535);
    check(&mut rng, false, 1, ho / 4, wo / 4, 3, ho, wo);
}

#[test]
fn nearest_matches_reference_exactly() {
    // PyTorch's mode='nearest' copies source pixels: the result must be exact. Arbitrary ratios, the 2×
    // and k× special cases, and the official output resize (56×80 from a 7×10 patch grid at k=8 → 60×80).
    let mut rng = Rng::new(15);
    let mut cases: Vec<(usize, usize, usize, usize, usize)> =
        vec![(7, 5, 14, 10, 3), (40, 48, 10, 6, 5), (56, 80, 60, 80, 3), (56, 80, 60, 80, 4)];
    for _ in 0..12 {
        cases.push((rng.range(1, 25), rng.range(1, 25), rng.range(1, 25), rng.range(1, 25), CHANNELS[rng.range(0, 2)]));
    }
    for (hi, wi, ho, wo, c) in cases {
        let n = rng.range(1, 2);
        let what = format!("nearest {n}x{hi}x{wi}x{c} -> {ho}x{wo}");
        let x = rng.vec_f32(n * hi * wi * c, -1.0, 1.0);
        let xp = Placed::new(&mut rng, "x", &x, c, 0.0);
        let op = Placed::new(&mut rng, "out", &vec![0.0; n * ho * wo * c], c, f32::NAN);
        let mut plan = PlanBuilder::new();
        let (xv, ov) = (xp.view(&mut plan, "x"), op.view(&mut plan, "out"));
        let args = ResizeArgs { x: xv, n, from: (hi, wi), out: ov, to: (ho, wo), accumulate: false };
        nearest(&mut plan, "resize", args);
        run(plan);
        let got = op.read_view(&what);
        assert_close(&what, &got, &reference::nearest(&to_f64(&x), n, hi, wi, c, ho, wo), 0.0, 0.0);
    }
}
