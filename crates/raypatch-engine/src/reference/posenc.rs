//! Float64 reference of the Fourier positional encoding.

/// The encoding of `rows_out` output rows, `[rows_out, 6N]` with `N = multipliers.len()`: output row `r`
/// encodes coordinate row `(first_row + r) / repeat` of `coords` (`[R, 3]`) as
/// `[sin(c0·m_0..m_{N-1}), sin(c1·…), sin(c2·…), cos(c0·…), cos(c1·…), cos(c2·…)]`.
///
/// The argument is first rounded to f32, `a = f32(f32(c) · m)`, and only then taken to f64: torch computes
/// `coords * multipliers` in float32, and at the top octaves (|a| ~ 5e5, where an f32 ulp is 0.03) that
/// rounding moves the phase by up to 0.016 rad. The model was trained on those rounded arguments, so the
/// reference reproduces them and is exact (to f64) from there on.
pub fn fourier_encode(
    coords: &[f64],
    repeat: usize,
    first_row: usize,
    rows_out: usize,
    multipliers: &[f32],
) -> Vec<f64> {
    let n = multipliers.len();
    let mut out = Vec::with_capacity(rows_out * 6 * n);
    for r in 0..rows_out {
        let c = &coords[(first_row + r) / repeat * 3..][..3];
        let args: Vec<f64> = c.iter().flat_map(|&c| multipliers.iter().map(move |&m| (c as f32 * m) as f64)).collect();
        out.extend(args.iter().map(|a| a.sin()));
        out.extend(args.iter().map(|a| a.cos()));
    }
    out
}
