//! Row mixes `out = w · x` against the float64 reference.
//!
//! Each output element is an f32 sum of n products taken in order, so it is within (n + 1)·u of
//! Σ_i |w[r, i]|·|x[i, c]| of exact (products and additions each round once; an fma rounds less). The tests
//! check that bound element by element, with the bound computed from the same inputs.

use std::ops::Range;

use raypatch_engine::kernels::mix::{mix_rows, MixArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::mix as reference;

use crate::common::*;

const SENTINEL: f32 = 9.125;
/// f32 unit roundoff.
const U: f64 = 1.0 / (1u64 << 24) as f64;

/// Mixes the whole `x` (`[n, cols]`) by rows `w_rows` of `w` (`[w.len() / n, n]`) into as many rows from
/// `out_start` of an `out_total`-row output prefilled with SENTINEL (padding included). Checks that the
/// view's padding is zero and every other row untouched; returns the view's rows, unpadded.
fn run_mix(
    w: &[f32],
    n: usize,
    w_rows: Range<usize>,
    x: &[f32],
    cols: usize,
    out_total: usize,
    out_start: usize,
) -> Vec<f32> {
    let gpu = gpu();
    let rows = w_rows.len();
    let wt = gpu.upload("w", w.len() / n, n, w).unwrap();
    let xt = gpu.upload("x", n, cols, x).unwrap();
    let out = sentinel_tensor(out_total, cols, SENTINEL);
    let mut b = PlanBuilder::new();
    let (wi, xi, oi) = (b.external("w", &wt), b.external("x", &xt), b.external("out", &out));
    let (wv, ov) = (b.rows_of(wi, w_rows.start, rows), b.rows_of(oi, out_start, rows));
    mix_rows(&mut b, "mix", MixArgs { w: wv, x: xi, out: ov });
    run(b);
    read_written_rows(&out, out_start..out_start + rows, SENTINEL)
}

/// Runs one case on random data and checks it element by element against (n + 1)·u·Σ|w||x|, the bound of
/// an in-order f32 sum of n products (plus an ulp of slack for the last rounding). Returns the largest
/// absolute error and the largest error as a fraction of its element's bound.
fn check(rng: &mut Rng, rows: usize, n: usize, cols: usize, w_start: usize, out_start: usize) -> (f64, f64) {
    let w_total = w_start + rows + rng.range(0, 20);
    // Softmax-like weights in [0, 1) mostly, some negative ones too; x of either sign.
    let w = rng.vec_f32(w_total * n, -0.25, 1.0);
    let x = rng.vec_f32(n * cols, -3.0, 3.0);
    let got = run_mix(&w, n, w_start..w_start + rows, &x, cols, out_start + rows + rng.range(0, 20), out_start);
    let wv = to_f64(&w[w_start * n..(w_start + rows) * n]);
    let want = reference::mix_rows(&wv, n, &to_f64(&x), cols);
    let abs = |v: &[f64]| v.iter().map(|a| a.abs()).collect::<Vec<_>>();
    let magnitude = reference::mix_rows(&abs(&wv), n, &abs(&to_f64(&x)), cols);
    let what = format!("mix {rows}x{n} · {n}x{cols} from rows {w_start}/{out_start}");
    let (mut max_abs, mut max_frac) = (0.0f64, 0.0f64);
    for (i, ((&g, &e), &m)) in got.iter().zip(&want).zip(&magnitude).enumerate() {
        let bound = (n as f64 + 1.0) * U * m + U * e.abs();
        let err = if g.is_finite() { (g as f64 - e).abs() } else { f64::INFINITY };
        assert!(err <= bound, "{what}: element {i} is {g:e}, want {e:e} (bound {bound:e})");
        max_abs = max_abs.max(err);
        if bound > 0.0 {
            max_frac = max_frac.max(err / bound);
        }
    }
    (max_abs, max_frac)
}

/// n = 1..40 (slots), random rows and columns including ones that are not multiples of 4, views at row offsets.
#[test]
fn mix_rows_every_small_n() {
    let mut rng = Rng::new(51);
    let (mut worst_abs, mut worst_frac) = (0.0f64, 0.0f64);
    for n in 1..=40 {
        let rows = rng.range(1, 150);
        let cols = if n % 3 == 0 { rng.range(1, 9) } else { rng.range(1, 200) };
        let (w_start, out_start) = (64 * rng.range(0, 2), 64 * rng.range(0, 2));
        let (abs, frac) = check(&mut rng, rows, n, cols, w_start, out_start);
        (worst_abs, worst_frac) = (worst_abs.max(abs), worst_frac.max(frac));
    }
    eprintln!("mix_rows n 1..40: max abs error {worst_abs:e}, max fraction of the bound {worst_frac:.3}");
}

/// The slot-attention shape: few rows (slots), a long n (inputs) and wide rows.
#[test]
fn mix_rows_wide() {
    let mut rng = Rng::new(52);
    let (mut worst_abs, mut worst_frac) = (0.0f64, 0.0f64);
    for (rows, n, cols, w_start, out_start) in [(5, 300, 1536, 0, 0), (5, 300, 1536, 64, 64), (3, 257, 1023, 64, 0)] {
        let (abs, frac) = check(&mut rng, rows, n, cols, w_start, out_start);
        (worst_abs, worst_frac) = (worst_abs.max(abs), worst_frac.max(frac));
    }
    eprintln!("mix_rows wide: max abs error {worst_abs:e}, max fraction of the bound {worst_frac:.3}");
}

/// One-hot weights copy rows of x exactly.
#[test]
fn mix_rows_one_hot_copies() {
    let mut rng = Rng::new(53);
    let (rows, n, cols) = (9, 6, 13);
    let x = rng.vec_f32(n * cols, -1e6, 1e6);
    let picks: Vec<usize> = (0..rows).map(|_| rng.range(0, n - 1)).collect();
    let mut w = vec![0.0f32; rows * n];
    for (r, &i) in picks.iter().enumerate() {
        w[r * n + i] = 1.0;
    }
    let got = run_mix(&w, n, 0..rows, &x, cols, rows, 0);
    for (r, &i) in picks.iter().enumerate() {
        assert_eq!(&got[r * cols..(r + 1) * cols], &x[i * cols..(i + 1) * cols], "row {r} should be row {i} of x");
    }
}
