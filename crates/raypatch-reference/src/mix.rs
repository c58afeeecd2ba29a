//! Float64 reference of the row mix.

/// `out[r, :] = Σ_i w[r, i] · x[i, :]` (`out = w · x`) for row-major `w` `[rows, n]` and `x` `[n, cols]`;
/// returns `[rows, cols]`.
pub fn mix_rows(w: &[f64], n: usize, x: &[f64], cols: usize) -> Vec<f64> {
    assert!(n > 0 && cols > 0 && w.len().is_multiple_of(n) && x.len() == n * cols, "mix_rows: shape mismatch");
    let mut out = vec![0.0; w.len() / n * cols];
    for (wr, or) in w.chunks(n).zip(out.chunks_mut(cols)) {
        for (wi, xi) in wr.iter().zip(x.chunks(cols)) {
            for (o, v) in or.iter_mut().zip(xi) {
                *o += wi * v;
            }
        }
    }
    out
}
