//! Float64 reference of the elementwise column map.

use raypatch_engine::kernels::elementwise::Map;

/// `out[r, j] = f(x[r, col + j])` for `j < cols_out`, on a row-major `[rows, cols_x]` matrix.
pub fn map_columns(x: &[f64], cols_x: usize, col: usize, cols_out: usize, f: Map) -> Vec<f64> {
    assert!(col + cols_out <= cols_x && x.len().is_multiple_of(cols_x), "map_columns: shape mismatch");
    x.chunks(cols_x)
        .flat_map(|row| row[col..col + cols_out].iter())
        .map(|&v| {
            let sigmoid = 1.0 / (1.0 + (-v).exp());
            match f {
                Map::Identity => v,
                Map::Sigmoid => sigmoid,
                Map::Exp => v.exp(),
                Map::SigmoidAffine { scale, offset } => sigmoid * scale as f64 + offset as f64,
                Map::LogSigmoidAffine { scale, offset } => (sigmoid * scale as f64 + offset as f64).ln(),
            }
        })
        .collect()
}
