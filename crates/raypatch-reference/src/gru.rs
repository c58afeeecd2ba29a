//! Float64 reference of the GRU cell's gates.

fn sigmoid(v: f64) -> f64 {
    1.0 / (1.0 + (-v).exp())
}

/// PyTorch's `nn.GRUCell` from its two gate projections: `gi = x·W_ihᵀ + b_ih` and `gh = h·W_hhᵀ + b_hh`,
/// row-major `[rows, 3·dim]` with the gates in the order r, z, n, and the previous state `h` `[rows, dim]`:
/// `r = σ(gi_r + gh_r)`, `z = σ(gi_z + gh_z)`, `n = tanh(gi_n + r·gh_n)`, `out = (1 - z)·n + z·h`.
/// Returns `[rows, dim]`.
pub fn gru_cell(gi: &[f64], gh: &[f64], h: &[f64], dim: usize) -> Vec<f64> {
    assert!(dim > 0 && h.len().is_multiple_of(dim), "gru_cell: shape mismatch");
    assert!(gi.len() == 3 * h.len() && gh.len() == gi.len(), "gru_cell: gates are not [rows, 3·dim]");
    let mut out = Vec::with_capacity(h.len());
    for ((gi, gh), h) in gi.chunks(3 * dim).zip(gh.chunks(3 * dim)).zip(h.chunks(dim)) {
        for (j, &prev) in h.iter().enumerate() {
            let r = sigmoid(gi[j] + gh[j]);
            let z = sigmoid(gi[dim + j] + gh[dim + j]);
            let n = (gi[2 * dim + j] + r * gh[2 * dim + j]).tanh();
            out.push((1.0 - z) * n + z * prev);
        }
    }
    out
}
