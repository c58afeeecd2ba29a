//! Float64 references of the softmax kernels.

use raypatch_engine::kernels::softmax::Axis;

/// `softmax(scale · x) + eps` along `axis` of a row-major `[rows, cols]` matrix, the maximum subtracted
/// before exp (PyTorch's `(x * scale).softmax(dim) + eps`).
pub fn softmax(x: &[f64], cols: usize, axis: Axis, scale: f64, eps: f64) -> Vec<f64> {
    assert!(cols > 0 && x.len().is_multiple_of(cols), "softmax: shape mismatch");
    let rows = x.len() / cols;
    // (first, stride, len) of each softmax.
    let lines: Vec<(usize, usize, usize)> = match axis {
        Axis::Rows => (0..rows).map(|r| (r * cols, 1, cols)).collect(),
        Axis::Columns => (0..cols).map(|c| (c, cols, rows)).collect(),
    };
    let mut out = vec![0.0; x.len()];
    for (first, stride, len) in lines {
        let at = |i: usize| first + i * stride;
        let max = (0..len).map(|i| scale * x[at(i)]).fold(f64::NEG_INFINITY, f64::max);
        let sum: f64 = (0..len).map(|i| (scale * x[at(i)] - max).exp()).sum();
        for i in 0..len {
            out[at(i)] = (scale * x[at(i)] - max).exp() / sum + eps;
        }
    }
    out
}

/// `out[r, :] = x[r, :] / Σ x[r, :]` for every row of a row-major `[rows, cols]` matrix.
pub fn normalize_rows(x: &[f64], cols: usize) -> Vec<f64> {
    assert!(cols > 0 && x.len().is_multiple_of(cols), "normalize_rows: shape mismatch");
    x.chunks(cols)
        .flat_map(|row| {
            let sum: f64 = row.iter().sum();
            row.iter().map(move |v| v / sum)
        })
        .collect()
}
