//! Column concatenation against the float64 reference: a copy, so bit exact.

use raypatch_engine::kernels::concat::concat_columns;
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::concat as reference;

use crate::common::*;

const SENTINEL: f32 = -2.625;

/// Concatenates rows `a_start..a_start + rows` of `a` and `b_start..` of `b` into as many rows from `out_start`
/// of an `out_total`-row output prefilled with SENTINEL (padding included). Checks that the view's padding is
/// zero and every other row untouched; returns the view's rows, unpadded.
#[allow(clippy::too_many_arguments)]
fn run_concat(
    a: &[f32],
    a_cols: usize,
    a_start: usize,
    b: &[f32],
    b_cols: usize,
    b_start: usize,
    rows: usize,
    out_total: usize,
    out_start: usize,
) -> Vec<f32> {
    let gpu = gpu();
    let at = gpu.upload("a", a.len() / a_cols, a_cols, a).unwrap();
    let bt = gpu.upload("b", b.len() / b_cols, b_cols, b).unwrap();
    let out = sentinel_tensor(out_total, a_cols + b_cols, SENTINEL);
    let mut plan = PlanBuilder::new();
    let (ai, bi, oi) = (plan.external("a", &at), plan.external("b", &bt), plan.external("out", &out));
    let (av, bv, ov) =
        (plan.rows_of(ai, a_start, rows), plan.rows_of(bi, b_start, rows), plan.rows_of(oi, out_start, rows));
    concat_columns(&mut plan, "concat", av, bv, ov);
    run(plan);
    read_written_rows(&out, out_start..out_start + rows, SENTINEL)
}

#[test]
fn concat_columns_random_shapes_and_views() {
    let mut rng = Rng::new(61);
    let mut shapes: Vec<(usize, usize)> = vec![(1, 1), (1, 3), (3, 1), (2, 2), (4, 4), (5, 7), (3, 180), (768, 180)];
    shapes.extend((0..10).map(|_| (rng.range(1, 300), rng.range(1, 300))));
    for (a_cols, b_cols) in shapes {
        let rows = rng.range(1, 200);
        let (a_start, b_start, out_start) = (64 * rng.range(0, 2), 64 * rng.range(0, 2), 64 * rng.range(0, 2));
        let (a_rows, b_rows) = (a_start + rows + rng.range(0, 10), b_start + rows + rng.range(0, 10));
        let a = rng.vec_f32(a_rows * a_cols, -1e3, 1e3);
        let b = rng.vec_f32(b_rows * b_cols, -1e3, 1e3);
        let got =
            run_concat(&a, a_cols, a_start, &b, b_cols, b_start, rows, out_start + rows + rng.range(0, 10), out_start);
        let want = reference::concat_columns(
            &to_f64(&a[a_start * a_cols..(a_start + rows) * a_cols]),
            a_cols,
            &to_f64(&b[b_start * b_cols..(b_start + rows) * b_cols]),
            b_cols,
        );
        // A copy: bit exact.
        let what = format!("concat {rows}x{a_cols} and {rows}x{b_cols} from rows {a_start}/{b_start}/{out_start}");
        assert_close(&what, &got, &want, 0.0, 0.0);
    }
}

/// Non-finite values and signed zeros are copied as they are (bit for bit).
#[test]
fn concat_columns_copies_bits() {
    let a = [f32::NAN, -0.0, f32::INFINITY, 1e-40, -1.5, 3.0];
    let b = [f32::NEG_INFINITY, 0.0, -1e-45, f32::MAX];
    let got = run_concat(&a, 3, 0, &b, 2, 0, 2, 2, 0);
    let want = [a[0], a[1], a[2], b[0], b[1], a[3], a[4], a[5], b[2], b[3]];
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&got), bits(&want));
}
