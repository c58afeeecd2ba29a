//! Softmax along rows and columns, and row normalisation, against the float64 reference, each as the CPU
//! adapters' and the GPUs' kernel families run it (a row softmax: an invocation or a workgroup per row).
//!
//! The outputs are probabilities that slot attention renormalises over inputs, so errors are checked
//! relative to each element, not to the largest.

use std::ops::Range;

use raypatch_engine::device::{KernelChoice, MatmulKernel};
use raypatch_engine::kernels::softmax::{normalize_rows, softmax, Axis, SoftmaxArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::softmax as reference;

use crate::common::*;

const SENTINEL: f32 = -6.5;
/// f32 unit roundoff.
const U: f64 = 1.0 / (1u64 << 24) as f64;
/// 1/√128, the logit scale of 128-wide slots (not a power of two: the scaled logits round).
const INV_SQRT_128: f32 = std::f32::consts::FRAC_1_SQRT_2 / 8.0;
/// The official slot attention's eps.
const SLOT_EPS: f32 = 1e-8;
/// Below f32's smallest normal (1.2e-38) exp underflows (to 0 where denormals are flushed): nothing
/// relative survives there.
const UNDERFLOW: f64 = 1.2e-38;

#[derive(Clone, Copy, Debug)]
enum Which {
    Softmax { axis: Axis, scale: f32, eps: f32 },
    NormalizeRows,
}

/// Runs `which` on rows `x_rows` of `x` (`[x.len() / cols, cols]`) into as many rows from `out_start` of an
/// `out_total`-row output prefilled with SENTINEL (padding included), as the CPU adapters' family (`Rows`) and
/// the GPUs' (`Tiled`) run it. Checks that the view's padding is zero and every other row untouched; returns
/// each family's view rows, unpadded.
fn run_op(
    x: &[f32],
    cols: usize,
    x_rows: Range<usize>,
    out_total: usize,
    out_start: usize,
    which: Which,
) -> Vec<(MatmulKernel, Vec<f32>)> {
    let gpu = gpu();
    let rows = x_rows.len();
    let xt = gpu.upload("x", x.len() / cols, cols, x).unwrap();
    [MatmulKernel::Rows, MatmulKernel::Tiled]
        .into_iter()
        .map(|kernel| {
            let out = sentinel_tensor(out_total, cols, SENTINEL);
            let mut b = PlanBuilder::new();
            b.kernels = KernelChoice { matmul: kernel, ..gpu.kernels };
            let (xi, oi) = (b.external("x", &xt), b.external("out", &out));
            let (xv, ov) = (b.rows_of(xi, x_rows.start, rows), b.rows_of(oi, out_start, rows));
            match which {
                Which::Softmax { axis, scale, eps } => {
                    softmax(&mut b, "softmax", SoftmaxArgs { x: xv, out: ov, axis, scale, eps })
                }
                Which::NormalizeRows => normalize_rows(&mut b, "normalize", xv, ov),
            }
            run(b);
            (kernel, read_written_rows(&out, out_start..out_start + rows, SENTINEL))
        })
        .collect()
}

/// Asserts |got - want| <= atol + rtol·|want| element by element; returns the largest absolute and relative
/// (to |want|, where |want| > atol) errors.
fn assert_close_each(what: &str, got: &[f32], want: &[f64], atol: f64, rtol: f64) -> (f64, f64) {
    assert_eq!(got.len(), want.len(), "{what}: length mismatch");
    let (mut max_abs, mut max_rel) = (0.0f64, 0.0f64);
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        let err = if g.is_finite() { (g as f64 - w).abs() } else { f64::INFINITY };
        assert!(
            err <= atol + rtol * w.abs(),
            "{what}: element {i} is {g:e}, want {w:e} (atol {atol:e}, rtol {rtol:e})"
        );
        max_abs = max_abs.max(err);
        if w.abs() > atol {
            max_rel = max_rel.max(err / w.abs());
        }
    }
    (max_abs, max_rel)
}

/// Relative error allowed per probability of a softmax over `n` values. `d_err` bounds the absolute error of
/// each v_i − m before exp: it moves exp(v_i − m) relatively by as much and the sum too (2·d_err). `d` bounds
/// |v_i − m| where exp does not underflow: exp's own error is (2d + 8)·u (`tests/kernels/elementwise.rs`).
/// The f32 sum of n positive terms adds n·u, exp's errors on its terms up to n·u more, and the division and
/// + eps 8u.
fn softmax_rtol(d_err: f64, d: f64, n: usize) -> f64 {
    2.0 * d_err + U * (2.0 * d.min(MAX_EXP_ARG) + 8.0) + U * (2.0 * n as f64 + 8.0)
}

/// Past |v − m| = 88 exp(v − m) is below f32's smallest normal: only UNDERFLOW counts there.
const MAX_EXP_ARG: f64 = 88.0;

/// `softmax_rtol` for f32 logits computed from x with |scale·x| ≤ L: v_i and m are each off by u·L and the
/// difference rounds by u·|v_i − m| ≤ 2u·L.
fn rounded_logits_rtol(logit_max: f64, n: usize) -> f64 {
    softmax_rtol(4.0 * U * logit_max, 2.0 * logit_max, n)
}

/// The f32 logits `x·scale` the kernel computes, as f64.
fn f32_logits(x: &[f32], scale: f32) -> Vec<f64> {
    x.iter().map(|&v| f64::from(v * scale)).collect()
}

#[test]
fn softmax_random_shapes_and_views() {
    let mut rng = Rng::new(41);
    let (mut worst_abs, mut worst_rel) = (0.0f64, 0.0f64);
    for case in 0..24 {
        let axis = if case % 2 == 0 { Axis::Rows } else { Axis::Columns };
        // Rows: few columns (slots, 1..32) or many; columns: the softmax runs over the rows.
        let cols = [rng.range(1, 9), rng.range(1, 40), rng.range(40, 300)][case / 2 % 3];
        let rows = rng.range(1, 300);
        let (x_start, out_start) = (64 * rng.range(0, 2), 64 * rng.range(0, 2));
        let x_rows = x_start + rows + rng.range(0, 30);
        let range = rng.uniform(0.5, 12.0);
        let x = rng.vec_f32(x_rows * cols, -range, range);
        let scale = [1.0, 0.125, INV_SQRT_128, rng.uniform(0.05, 2.0) as f32][rng.range(0, 3)];
        let eps = if case % 3 == 0 { 0.0 } else { SLOT_EPS };
        let which = Which::Softmax { axis, scale, eps };
        let out_total = out_start + rows + rng.range(0, 30);
        let view = &x[x_start * cols..(x_start + rows) * cols];
        let want = reference::softmax(&to_f64(view), cols, axis, scale as f64, eps as f64);
        let logit_max = view.iter().fold(0.0f64, |m, &v| m.max((v as f64 * scale as f64).abs()));
        let n = if axis == Axis::Rows { cols } else { rows };
        for (kernel, got) in run_op(&x, cols, x_start..x_start + rows, out_total, out_start, which) {
            let what = format!(
                "{kernel:?}: softmax {axis:?} {rows}x{cols} scale {scale} eps {eps} from rows {x_start}/{out_start}"
            );
            let (abs, rel) = assert_close_each(&what, &got, &want, 0.0, rounded_logits_rtol(logit_max, n));
            (worst_abs, worst_rel) = (worst_abs.max(abs), worst_rel.max(rel));
        }
    }
    eprintln!("softmax random: max abs error {worst_abs:e}, max relative error {worst_rel:e}");
}

/// Logits of ±1e4·scale neither overflow nor give NaN. With integer x and a power-of-two scale the f32 logits
/// are exact and so is v − m (integers below 2^24): what remains is exp, the sum and the division.
#[test]
fn softmax_large_exact_logits() {
    let mut rng = Rng::new(42);
    let mut worst_rel = 0.0f64;
    for (axis, rows, cols, scale, eps) in [
        (Axis::Rows, 70, 7, 0.125, SLOT_EPS),
        (Axis::Rows, 33, 64, 1.0, 0.0),
        (Axis::Columns, 7, 130, 0.125, SLOT_EPS),
        (Axis::Columns, 200, 5, 0.25, 0.0),
    ] {
        // Integers in [-1e4, 1e4], a few rows/columns close to their maximum so that several terms count.
        let mut x: Vec<f32> = (0..rows * cols).map(|_| rng.uniform(-1e4, 1e4).round() as f32).collect();
        for v in x.iter_mut().step_by(3) {
            *v = (1e4 - rng.range(0, 200) as f64) as f32;
        }
        let want = reference::softmax(&to_f64(&x), cols, axis, scale as f64, eps as f64);
        let n = if axis == Axis::Rows { cols } else { rows };
        for (kernel, got) in run_op(&x, cols, 0..rows, rows, 0, Which::Softmax { axis, scale, eps }) {
            // Exact logits and differences: only exp, the sum, the division and + eps.
            let what = format!("{kernel:?}: softmax {axis:?} {rows}x{cols} of integers up to 1e4, scale {scale}");
            let (_, rel) = assert_close_each(&what, &got, &want, UNDERFLOW, softmax_rtol(0.0, MAX_EXP_ARG, n));
            worst_rel = worst_rel.max(rel);
        }
    }
    eprintln!("softmax exact large logits: max relative error {worst_rel:e}");
}

/// Arbitrary f32 logits of ±1e4·scale: the f32 logit is itself off by up to u·1e4·scale, which
/// `rounded_logits_rtol` allows; the check is mainly that nothing overflows.
#[test]
fn softmax_large_rounded_logits() {
    let mut rng = Rng::new(43);
    let mut worst_rel = 0.0f64;
    for (axis, rows, cols, scale) in [(Axis::Rows, 65, 11, INV_SQRT_128), (Axis::Columns, 9, 37, 0.17)] {
        let mut x = rng.vec_f32(rows * cols, -1e4, 1e4);
        // Near-ties with the maximum, so that the result is not one-hot.
        for v in x.iter_mut().step_by(2) {
            *v = (1e4 - rng.uniform(0.0, 300.0)) as f32;
        }
        let eps = SLOT_EPS;
        let want = reference::softmax(&to_f64(&x), cols, axis, scale as f64, eps as f64);
        let n = if axis == Axis::Rows { cols } else { rows };
        // Against the f32 logits the kernel sees, only v − m's rounding (u·|v − m| where exp does not
        // underflow) and an fma the driver may fuse x·scale − m into (u·|v| off the f32 logit) remain.
        let want32 = reference::softmax(&f32_logits(&x, scale), cols, axis, 1.0, eps as f64);
        let rtol32 = softmax_rtol(U * (1e4 * scale as f64 + MAX_EXP_ARG), MAX_EXP_ARG, n);
        for (kernel, got) in run_op(&x, cols, 0..rows, rows, 0, Which::Softmax { axis, scale, eps }) {
            let what = format!("{kernel:?}: softmax {axis:?} {rows}x{cols} of x up to 1e4, scale {scale}");
            let rtol = rounded_logits_rtol(1e4 * scale as f64, n);
            let (_, rel) = assert_close_each(&what, &got, &want, UNDERFLOW, rtol);
            worst_rel = worst_rel.max(rel);
            assert_close_each(&format!("{what}, against the f32 logits"), &got, &want32, UNDERFLOW, rtol32);
        }
    }
    eprintln!("softmax rounded large logits: max relative error {worst_rel:e}");
}

/// One column: along rows every output is 1 + eps; along columns the softmax runs over the rows of the one
/// column and the three padding columns are zeroed by invocations of their own.
#[test]
fn softmax_one_column() {
    let mut rng = Rng::new(44);
    for axis in [Axis::Rows, Axis::Columns] {
        for (rows, x_start, out_start) in [(1, 0, 0), (5, 64, 0), (130, 0, 64)] {
            let x = rng.vec_f32(x_start + rows + 3, -5.0, 5.0);
            let (scale, eps) = (0.5, SLOT_EPS);
            let which = Which::Softmax { axis, scale, eps };
            let want = reference::softmax(&to_f64(&x[x_start..x_start + rows]), 1, axis, scale as f64, eps as f64);
            for (kernel, got) in run_op(&x, 1, x_start..x_start + rows, out_start + rows + 2, out_start, which) {
                let what = format!("{kernel:?}: softmax {axis:?} of {rows}x1 from rows {x_start}/{out_start}");
                if axis == Axis::Rows {
                    // exp(0) / exp(0) = 1 exactly, and 1 + 1e-8 rounds to 1 in f32.
                    assert!(got.iter().all(|&v| v == 1.0), "{what}: {got:?}");
                } else {
                    assert_close_each(&what, &got, &want, 0.0, rounded_logits_rtol(2.5, rows));
                }
            }
        }
    }
}

/// Flat inputs give exactly uniform weights (every exp is exp(0) = 1), and eps is added after the division.
#[test]
fn softmax_flat() {
    for (axis, rows, cols) in [(Axis::Rows, 3, 8), (Axis::Columns, 8, 6)] {
        let x = vec![123.25f32; rows * cols];
        for (kernel, got) in run_op(&x, cols, 0..rows, rows, 0, Which::Softmax { axis, scale: 0.3, eps: 0.5 }) {
            assert!(got.iter().all(|&v| v == 0.625), "{kernel:?}: softmax {axis:?} of a flat {rows}x{cols}: {got:?}");
        }
    }
}

#[test]
fn normalize_rows_random_shapes_and_views() {
    let mut rng = Rng::new(45);
    let mut worst_rel = 0.0f64;
    let mut widths = vec![1, 2, 3, 4, 5, 7, 8, 64, 65];
    widths.extend((0..7).map(|_| rng.range(1, 700)));
    for cols in widths {
        let rows = rng.range(1, 200);
        let (x_start, out_start) = (64 * rng.range(0, 2), 64 * rng.range(0, 2));
        let x_rows = x_start + rows + rng.range(0, 30);
        // Positive, as slot attention's softmax + eps is, over many orders of magnitude.
        let x: Vec<f32> = (0..x_rows * cols).map(|_| rng.uniform(-18.0, 0.0).exp() as f32).collect();
        let out_total = out_start + rows + rng.range(0, 30);
        let want = reference::normalize_rows(&to_f64(&x[x_start * cols..(x_start + rows) * cols]), cols);
        for (kernel, got) in run_op(&x, cols, x_start..x_start + rows, out_total, out_start, Which::NormalizeRows) {
            // The f32 sum of n positive terms is within (n − 1)·u relative, the division adds u.
            let what = format!("{kernel:?}: normalize_rows {rows}x{cols} from rows {x_start}/{out_start}");
            let (_, rel) = assert_close_each(&what, &got, &want, 0.0, U * (cols as f64 + 1.0));
            worst_rel = worst_rel.max(rel);
        }
    }
    eprintln!("normalize_rows: max relative error {worst_rel:e}");
}

/// The two steps of the official slot attention: softmax over slots (the rows of `[slots, inputs]` logits)
/// plus 1e-8, then renormalised over inputs; tiny weights stay relatively accurate through both.
#[test]
fn slot_attention_weights() {
    let gpu = gpu();
    let mut rng = Rng::new(46);
    let (slots, inputs, scale) = (7, 301, INV_SQRT_128);
    let x = rng.vec_f32(slots * inputs, -300.0, 300.0);
    let xt = gpu.upload("dots", slots, inputs, &x).unwrap();
    let mut b = PlanBuilder::new();
    let xi = b.external("dots", &xt);
    let (attn, out) = (b.transient("attn", slots, inputs), b.output("out", slots, inputs));
    let (xv, av, ov) = (b.all(xi), b.all(attn), b.all(out));
    softmax(&mut b, "softmax", SoftmaxArgs { x: xv, out: av, axis: Axis::Columns, scale, eps: SLOT_EPS });
    normalize_rows(&mut b, "normalize", av, ov);
    let plan = run(b);
    let got = gpu.read(&plan.tensor(out)).unwrap();
    let attn = reference::softmax(&to_f64(&x), inputs, Axis::Columns, scale as f64, SLOT_EPS as f64);
    let want = reference::normalize_rows(&attn, inputs);
    // The softmax's relative error (logits up to 300·scale = 27), then the normalisation's.
    let rtol = rounded_logits_rtol(300.0 * scale as f64, slots) + U * (inputs as f64 + 1.0);
    let (_, rel) = assert_close_each("slot attention weights", &got, &want, 0.0, rtol);
    eprintln!("slot attention weights: max relative error {rel:e}");
}
