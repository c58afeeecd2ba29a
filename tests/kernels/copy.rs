//! Copies into a column range (with a row broadcast) against the float64 reference: bit exact, and every
//! column outside the range untouched.

use raypatch_engine::kernels::copy::{copy_columns, CopyArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::padded_cols;
use raypatch_reference::copy as reference;

use crate::common::*;

const SENTINEL: f32 = 1.625;

#[test]
fn copy_columns_random_shapes_broadcasts_and_offsets() {
    let mut rng = Rng::new(71);
    for case in 0..14 {
        let x_cols = rng.range(1, 40);
        let out_cols = x_cols + rng.range(0, 40);
        let col = rng.range(0, out_cols - x_cols);
        let repeat = if case % 2 == 0 { 1 } else { rng.range(2, 50) };
        let rows = rng.range(1, 400);
        let first_row = if case % 3 == 0 { 0 } else { rng.range(0, 100) };
        let x_rows = (first_row + rows - 1) / repeat + 1 + rng.range(0, 3);
        let out_start = 64 * rng.range(0, 2);
        let out_total = out_start + rows + rng.range(0, 20);
        let x = rng.vec_f32(x_rows * x_cols, -1e3, 1e3);

        let gpu = gpu();
        let xt = gpu.upload("x", x_rows, x_cols, &x).unwrap();
        let out = sentinel_tensor(out_total, out_cols, SENTINEL);
        let mut b = PlanBuilder::new();
        let (xi, oi) = (b.external("x", &xt), b.external("out", &out));
        let (xv, ov) = (b.all(xi), b.rows_of(oi, out_start, rows));
        copy_columns(&mut b, "copy", CopyArgs { x: xv, repeat, first_row, out: ov, col });
        run(b);
        // The padded rows of out, all of them: the copied block, SENTINEL everywhere else (padding included).
        let ld = padded_cols(out_cols);
        let got = gpu.read_rows(&out.buffer, 0, out_total, ld).unwrap();
        let mut want = vec![SENTINEL as f64; out_total * ld];
        let block = &mut want[out_start * ld..(out_start + rows) * ld];
        reference::copy_columns(&to_f64(&x), x_cols, repeat, first_row, block, ld, col);
        let what = format!(
            "copy {x_rows}x{x_cols} into columns {col}.. of rows {out_start}..+{rows} of {out_total}x{out_cols}, repeat {repeat}, first row {first_row}"
        );
        assert_close(&what, &got, &want, 0.0, 0.0);
    }
}
