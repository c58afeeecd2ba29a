//! Fourier positional encoding of camera positions and ray directions (`shaders/posenc.wgsl`), as the
//! `PositionalEncoding` of SRT / RayPatchQuerying.

use super::POSENC;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

/// Rows per workgroup: one invocation per output row.
const ROWS_PER_GROUP: usize = 64;
/// Most multipliers one op takes (the params block holds 8 vec4s).
pub const MAX_OCTAVES: usize = 32;

params! {
    /// The uniform of `shaders/posenc.wgsl`.
    PosencParams {
        /// Output rows in the view.
        rows: u32,
        /// Output rows per coordinate row: coordinate row = (first_row + r) / repeat.
        repeat: u32,
        first_row: u32,
        /// N, the number of multipliers.
        octaves: u32,
        /// First output column this op writes.
        col: u32,
        /// Output row stride in floats.
        ld: u32,
        /// First padding column to zero (ld when this op does not write the last columns).
        pad_from: u32,
        /// Always 0: the shader XORs the bits of c·m with it so that c·m is rounded to f32 before the reduction.
        opaque_zero: u32,
        /// The multipliers, `m[i / 4][i % 4]`, zero past N (uniform arrays need a 16-byte element stride).
        m: [[f32; 4]; 8],
    }
}
const _: () = assert!(MAX_OCTAVES == 4 * 8, "PosencParams::m holds MAX_OCTAVES multipliers");

/// A Fourier encoding's operands: see [`fourier_encode`].
#[derive(Clone, Copy, Debug)]
pub struct FourierArgs<'a> {
    /// `[R, 3]` coordinates.
    pub coords: View,
    /// Output rows per coordinate row.
    pub repeat: usize,
    /// Index of `out`'s first row in the broadcast.
    pub first_row: usize,
    /// At most [`MAX_OCTAVES`].
    pub multipliers: &'a [f32],
    pub out: View,
    /// First column of `out` written.
    pub col: usize,
}

/// The official multipliers as f32, as the reference PyTorch code builds them (in float32 whatever the
/// input dtype).
/// - `end` None (arange form): `m_i = f32(2^(start+i)) · f32(π)`, `i < num_octaves`.
/// - `end` Some (linspace form, DeFiNe): `torch.linspace(start, end, num_octaves)` in f32, times `f32(π)`.
///   torch computes `step = (end - start) / (n - 1)` in f32, then `start + i·step` for `i < n/2` and
///   `end - (n-1-i)·step` above, each as one fused multiply-add (its CPU kernels are built with FMA and
///   nvcc contracts by default); `n = 1` gives `[start]`.
///
/// Every product is rounded to f32, as torch's float32 `*` does.
pub fn multipliers(num_octaves: usize, start: f64, end: Option<f64>) -> Vec<f32> {
    let pi = std::f32::consts::PI;
    let octaves: Vec<f32> =
        match end {
            None => (0..num_octaves).map(|i| (start + i as f64).exp2() as f32).collect(),
            Some(_) if num_octaves <= 1 => vec![start as f32; num_octaves],
            Some(end) => {
                let (start, end, n) = (start as f32, end as f32, num_octaves);
                let step = (end - start) / (n - 1) as f32;
                (0..n)
                    .map(|i| {
                        if i < n / 2 {
                            step.mul_add(i as f32, start)
                        } else {
                            (-step).mul_add((n - 1 - i) as f32, end)
                        }
                    })
                    .collect()
            }
        };
    octaves.into_iter().map(|o| o * pi).collect()
}

/// For output row `r` of `out`, with coordinate row `c = (first_row + r) / repeat` of `coords` (`[R, 3]`)
/// and `N = multipliers.len()`:
/// `out[r, col + d·N + i] = sin(f32(c_d · m_i))` and `out[r, col + 3N + d·N + i] = cos(f32(c_d · m_i))`:
/// `6N` columns, coordinate-major, the sin block then the cos block, like the reference's
/// `cat(sin(scaled).flatten(-2), cos(scaled).flatten(-2))`.
///
/// `repeat` broadcasts one coordinate row over `repeat` output rows (a view's camera position over its
/// rays); `first_row` is the index of `out`'s first row in that broadcast, so a chunk of rows can start
/// mid-tensor. Writes only columns `[col, col + 6N)` (other ops write the rest of the row), and zeroes the
/// row padding `[cols, ld)` when `col + 6N` is `out`'s last column.
///
/// The argument is rounded to f32 before sin/cos, as torch does; sin and cos are then accurate to
/// 1.2e-7 absolute for `|c_d · m_i| ≤ 2^20` (explicit range reduction, not the built-in sin/cos).
///
/// Records no multiply-adds: encodings are not multiply-add work worth counting.
pub fn fourier_encode(plan: &mut PlanBuilder, label: &str, args: FourierArgs) {
    let FourierArgs { coords, repeat, first_row, multipliers, out, col } = args;
    let n = multipliers.len();
    let cols = plan.cols(out.id);
    assert_eq!(plan.cols(coords.id), 3, "fourier_encode {label}: coords must have 3 columns");
    assert!((1..=MAX_OCTAVES).contains(&n), "fourier_encode {label}: {n} multipliers, expected 1..={MAX_OCTAVES}");
    assert!(repeat > 0, "fourier_encode {label}: repeat must be positive");
    assert!(
        out.rows == 0 || (first_row + out.rows - 1) / repeat < coords.rows,
        "fourier_encode {label}: rows {first_row}..{} with repeat {repeat} need more than {} coordinate rows",
        first_row + out.rows,
        coords.rows
    );
    assert!(col + 6 * n <= cols, "fourier_encode {label}: columns {col}..{} past the {cols} of out", col + 6 * n);
    assert!(coords.id != out.id, "fourier_encode {label}: coords and out must be different tensors");
    let ld = plan.ld(out.id);
    let pad_from = if col + 6 * n == cols { cols } else { ld };
    let mut m = [[0.0; 4]; MAX_OCTAVES / 4];
    for (i, &multiplier) in multipliers.iter().enumerate() {
        m[i / 4][i % 4] = multiplier;
    }
    let params = PosencParams {
        rows: out.rows as u32,
        repeat: repeat as u32,
        first_row: first_row as u32,
        octaves: n as u32,
        col: col as u32,
        ld: ld as u32,
        pad_from: pad_from as u32,
        opaque_zero: 0,
        m,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &POSENC,
        entry: "fourier_encode",
        params: params.words(),
        bindings: vec![(coords, Access::Read), (out, Access::ReadWrite)],
        textures: Vec::new(),
        workgroups: grid(out.rows.div_ceil(ROWS_PER_GROUP)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
