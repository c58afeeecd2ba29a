//! Float64 reference of the column concatenation.

/// `out[r, :] = cat(a[r, :], b[r, :])` for row-major `a` `[rows, a_cols]` and `b` `[rows, b_cols]`; returns
/// `[rows, a_cols + b_cols]` (`torch.cat((a, b), -1)`).
pub fn concat_columns(a: &[f64], a_cols: usize, b: &[f64], b_cols: usize) -> Vec<f64> {
    assert!(a_cols > 0 && b_cols > 0, "concat_columns: empty operand");
    assert!(a.len().is_multiple_of(a_cols) && b.len() == a.len() / a_cols * b_cols, "concat_columns: shape mismatch");
    a.chunks(a_cols).zip(b.chunks(b_cols)).flat_map(|(ar, br)| ar.iter().chain(br).copied()).collect()
}
