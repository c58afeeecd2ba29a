//! Elementwise column maps against the float64 reference.

use std::ops::Range;

use raypatch_engine::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::elementwise as reference;

use crate::common::*;

const SENTINEL: f32 = 3.75;

/// Maps columns `columns` of rows `x_rows` of `x` (`[rows, cols_x]`) into as many rows from `out_start` of an
/// `[out_total, columns.len()]` output prefilled with SENTINEL (padding included). Checks that the view's
/// padding is zero and every other row untouched; returns the view's rows, unpadded.
fn run_map(
    x: &[f32],
    cols_x: usize,
    x_rows: Range<usize>,
    columns: Range<usize>,
    out_total: usize,
    out_start: usize,
    f: Map,
) -> Vec<f32> {
    let gpu = gpu();
    let (rows, cols) = (x_rows.len(), columns.len());
    let xt = gpu.upload("x", x.len() / cols_x, cols_x, x).unwrap();
    let out = sentinel_tensor(out_total, cols, SENTINEL);
    let mut b = PlanBuilder::new();
    let (xi, oi) = (b.external("x", &xt), b.external("out", &out));
    let (xv, ov) = (b.rows_of(xi, x_rows.start, rows), b.rows_of(oi, out_start, rows));
    map_columns(&mut b, "map", MapColumnsArgs { x: xv, col: columns.start, out: ov, map: f });
    run(b);
    read_written_rows(&out, out_start..out_start + rows, SENTINEL)
}

/// Sigmoid error: exp is within a few ulp of its result (WGSL allows 3 + 2|x| ulp, relative to the tiny
/// e^-|x| for large |x|), then one division and one product: ~1e-7 at the outputs near 0.5..1 and far less
/// in the tail; 3e-7 absolute is ~5 ulp of 1.
const SIGMOID_TOL: f64 = 3e-7;

#[test]
fn map_columns_random_shapes_and_views() {
    let mut rng = Rng::new(31);
    for case in 0..20 {
        let affine = Map::SigmoidAffine { scale: 9.9, offset: 0.1 };
        let log_affine = Map::LogSigmoidAffine { scale: 9.9, offset: 0.1 };
        let f = [Map::Identity, Map::Sigmoid, Map::Exp, affine, log_affine][case % 5];
        let cols_x = rng.range(1, 70);
        let cols = rng.range(1, cols_x);
        let col = rng.range(0, cols_x - cols);
        let rows = rng.range(1, 300);
        let (x_start, out_start) = (64 * rng.range(0, 2), 64 * rng.range(0, 2));
        let x_rows = x_start + rows + rng.range(0, 30);
        let x = rng.vec_f32(x_rows * cols_x, -12.0, 12.0);
        let got = run_map(
            &x,
            cols_x,
            x_start..x_start + rows,
            col..col + cols,
            out_start + rows + rng.range(0, 30),
            out_start,
            f,
        );
        let want =
            reference::map_columns(&to_f64(&x[x_start * cols_x..(x_start + rows) * cols_x]), cols_x, col, cols, f);
        let what = format!("{f:?} of columns {col}..{} of {rows}x{cols_x} from rows {x_start}/{out_start}", col + cols);
        match f {
            // Identity is a copy: bit exact.
            Map::Identity => assert_close(&what, &got, &want, 0.0, 0.0),
            Map::Sigmoid => assert_close(&what, &got, &want, SIGMOID_TOL, 0.0),
            Map::Exp => {
                let xs = x.chunks(cols_x).skip(x_start).take(rows).flat_map(|row| &row[col..col + cols]);
                assert_exp_close(&what, xs.copied(), &got, &want);
            }
            // DeFiNe's depth in [0.1, 10]: the sigmoid's error times 9.9, then one rounding of the product
            // and the sum (a few ulp of 10).
            Map::SigmoidAffine { scale, .. } => {
                assert_close(&what, &got, &want, SIGMOID_TOL * scale as f64 + 4e-6, 0.0)
            }
            // Its log: the depth's relative error (at least 0.1, so ~4e-5 relative) plus log's own few ulp.
            Map::LogSigmoidAffine { .. } => assert_close(&what, &got, &want, 5e-5, 0.0),
        }
    }
}

/// f32 unit roundoff.
const U: f64 = 1.0 / (1u64 << 24) as f64;

/// exp's relative error allowed at x, WGSL's 3 + 2|x| ulp in the form GPUs reach it: exp(x) = 2^(x·log2 e),
/// where the rounding of x·log2 e gives up to u·|x| relative and that of log2 e itself ~0.25u·|x| more (2u·|x|
/// allowed), then exp2 within a few ulp (8u). Returns the largest error as a fraction of what is allowed.
fn assert_exp_close(what: &str, x: impl Iterator<Item = f32>, got: &[f32], want: &[f64]) -> f64 {
    let mut worst = 0.0f64;
    for ((x, &g), &w) in x.zip(got).zip(want) {
        let tol = U * (2.0 * x.abs() as f64 + 8.0) * w;
        let err = if g.is_finite() { (g as f64 - w).abs() } else { f64::INFINITY };
        assert!(err <= tol, "{what}: exp({x:e}) = {g:e}, want {w:e} (relative error {:e})", err / w);
        worst = worst.max(err / tol);
    }
    worst
}

/// exp over the whole range where its f32 result is normal, by relative error; beyond it exp overflows to
/// +inf and underflows to 0 (or a denormal), never NaN; and exp(±inf) = inf, 0.
#[test]
fn exp_accuracy() {
    // A dense sweep of [-87, 88] (ln of f32's smallest normal is -87.3, of its largest 88.7).
    let x: Vec<f32> = (0..=35000).map(|i| -87.0 + i as f32 * 0.005).collect();
    let got = run_map(&x, 1, 0..x.len(), 0..1, x.len(), 0, Map::Exp);
    let want = reference::map_columns(&to_f64(&x), 1, 0, 1, Map::Exp);
    let worst = assert_exp_close("exp over [-87, 88]", x.iter().copied(), &got, &want);
    let max_rel = got.iter().zip(&want).map(|(&g, &w)| (g as f64 - w).abs() / w).fold(0.0, f64::max);
    eprintln!("exp over [-87, 88]: max relative error {max_rel:e} ({worst:.3} of the tolerance)");

    let x = [89.0f32, 100.0, 1e30, f32::MAX, f32::INFINITY, -104.0, -1e30, -f32::MAX, f32::NEG_INFINITY];
    let got = run_map(&x, 1, 0..x.len(), 0..1, x.len(), 0, Map::Exp);
    for (&x, &g) in x.iter().zip(&got) {
        let ok = if x > 0.0 { g == f32::INFINITY } else { (0.0..1.2e-38).contains(&g) };
        assert!(ok, "exp({x:e}) = {g:e}");
    }
}

/// Large and infinite inputs neither overflow nor give NaN.
#[test]
fn sigmoid_extremes() {
    let magnitudes = [0.0f32, 1e-8, 0.5, 15.0, 17.0, 20.0, 88.0, 88.8, 100.0, 1e30, f32::MAX, f32::INFINITY];
    let x: Vec<f32> = magnitudes.iter().flat_map(|&v| [v, -v]).collect();
    let got = run_map(&x, 1, 0..x.len(), 0..1, x.len(), 0, Map::Sigmoid);
    let want = reference::map_columns(&to_f64(&x), 1, 0, 1, Map::Sigmoid);
    assert_close("sigmoid of extreme inputs", &got, &want, SIGMOID_TOL, 0.0);
    // The tail keeps its relative accuracy (e^x / (1 + e^x), not 1 - 1 / (1 + e^-x)).
    for (i, (&g, &w)) in got.iter().zip(&want).enumerate().filter(|(_, (_, &w))| (1e-30..1e-6).contains(&w)) {
        assert!((g as f64 - w).abs() <= 1e-5 * w, "sigmoid({}) = {g:e}, want {w:e}", x[i]);
    }
}

/// More than 65535 workgroups: the dispatch spills into the grid's second dimension.
#[test]
fn map_columns_grid_spill() {
    let mut rng = Rng::new(32);
    let rows = 65535 * 64 + 1000;
    let x = rng.vec_f32(rows * 2, -1.0, 1.0);
    let got = run_map(&x, 2, 0..rows, 1..2, rows, 0, Map::Identity);
    let want = reference::map_columns(&to_f64(&x), 2, 1, 1, Map::Identity);
    assert_close("identity over 4.2M rows", &got, &want, 0.0, 0.0);
}
