//! Float64 reference of the column copy with row broadcast.

/// `out[r, col + j] = x[(first_row + r) / repeat, j]` for every row of the row-major `[rows, out_cols]`
/// `out` and `j < x_cols`; other columns of `out` keep their values.
pub fn copy_columns(
    x: &[f64],
    x_cols: usize,
    repeat: usize,
    first_row: usize,
    out: &mut [f64],
    out_cols: usize,
    col: usize,
) {
    assert!(col + x_cols <= out_cols && out.len().is_multiple_of(out_cols), "copy_columns: shape mismatch");
    for (r, row) in out.chunks_mut(out_cols).enumerate() {
        let src = (first_row + r) / repeat;
        row[col..col + x_cols].copy_from_slice(&x[src * x_cols..(src + 1) * x_cols]);
    }
}
