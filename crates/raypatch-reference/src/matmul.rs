//! Float64 reference of the linear layer (`kernels::matmul::linear`).

use crate::activation;
use raypatch_engine::kernels::Activation;

/// `act(x · wᵀ + bias) (+ residual)` for x `[m, k]`, w `[n, k]` (nn.Linear layout), bias `[n]`,
/// residual `[m, n]`; returns `[m, n]`. The activation is applied before the residual add.
#[allow(clippy::too_many_arguments)]
pub fn linear(
    x: &[f64],
    m: usize,
    k: usize,
    w: &[f64],
    n: usize,
    bias: Option<&[f64]>,
    act: Activation,
    residual: Option<&[f64]>,
) -> Vec<f64> {
    assert_eq!(x.len(), m * k, "reference linear: x is not [{m}, {k}]");
    assert_eq!(w.len(), n * k, "reference linear: w is not [{n}, {k}]");
    assert!(bias.is_none_or(|b| b.len() == n), "reference linear: bias is not [{n}]");
    assert!(residual.is_none_or(|r| r.len() == m * n), "reference linear: residual is not [{m}, {n}]");
    let mut out = Vec::with_capacity(m * n);
    for i in 0..m {
        let row = &x[i * k..(i + 1) * k];
        for j in 0..n {
            let dot: f64 = row.iter().zip(&w[j * k..(j + 1) * k]).map(|(a, b)| a * b).sum();
            let value = activation(dot + bias.map_or(0.0, |b| b[j]), act);
            out.push(value + residual.map_or(0.0, |r| r[i * n + j]));
        }
    }
    out
}
