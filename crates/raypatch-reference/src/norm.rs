//! Float64 reference of the layer normalisation kernel.

/// PyTorch `nn.LayerNorm` over the last dimension of a row-major `[rows, cols]` matrix:
/// `out[r] = (x[r] - mean) / sqrt(var + eps) * gamma + beta`, with the biased variance (divide by `cols`),
/// computed in two passes.
pub fn layernorm(x: &[f64], cols: usize, gamma: &[f64], beta: &[f64], eps: f64) -> Vec<f64> {
    assert!(gamma.len() == cols && beta.len() == cols && x.len().is_multiple_of(cols), "layernorm: shape mismatch");
    let mut out = Vec::with_capacity(x.len());
    for row in x.chunks(cols) {
        let mean = row.iter().sum::<f64>() / cols as f64;
        let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / cols as f64;
        let rstd = 1.0 / (var + eps).sqrt();
        out.extend(row.iter().zip(gamma.iter().zip(beta)).map(|(v, (g, b))| (v - mean) * rstd * g + b));
    }
    out
}
