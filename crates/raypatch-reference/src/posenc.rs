//! Float64 reference of the Fourier positional encoding.

/// How the argument `c·m` of sin and cos is formed from an f32 coordinate `c` and an f32 multiplier `m`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Argument {
    /// `f32(c · m)`: torch computes `coords * multipliers` in float32, as does the engine. At the top octaves
    /// (|a| ~ 5e5, where an f32 ulp is 0.03) that rounding moves the phase by up to 0.016 rad; the model was
    /// trained on those rounded arguments.
    RoundedToF32,
    /// `c · m` in float64 (the multipliers stay the f32 values): what a float64 torch run computes.
    Float64,
}

/// The encoding of `rows_out` output rows, `[rows_out, 6N]` with `N = multipliers.len()`: output row `r`
/// encodes coordinate row `(first_row + r) / repeat` of `coords` (`[R, 3]`) as
/// `[sin(c0·m_0..m_{N-1}), sin(c1·…), sin(c2·…), cos(c0·…), cos(c1·…), cos(c2·…)]`, with the arguments
/// rounded to f32 as torch and the kernel round them ([`Argument::RoundedToF32`]); exact (to f64) from there on.
pub fn fourier_encode(
    coords: &[f64],
    repeat: usize,
    first_row: usize,
    rows_out: usize,
    multipliers: &[f32],
) -> Vec<f64> {
    fourier_encode_with(coords, repeat, first_row, rows_out, multipliers, Argument::RoundedToF32)
}

/// [`fourier_encode`] with the arguments formed as `argument` says.
pub fn fourier_encode_with(
    coords: &[f64],
    repeat: usize,
    first_row: usize,
    rows_out: usize,
    multipliers: &[f32],
    argument: Argument,
) -> Vec<f64> {
    let n = multipliers.len();
    let mut out = Vec::with_capacity(rows_out * 6 * n);
    for r in 0..rows_out {
        let c = &coords[(first_row + r) / repeat * 3..][..3];
        let args: Vec<f64> = c
            .iter()
            .flat_map(|&c| {
                multipliers.iter().map(move |&m| match argument {
                    Argument::RoundedToF32 => (c as f32 * m) as f64,
                    Argument::Float64 => c * m as f64,
                })
            })
            .collect();
        out.extend(args.iter().map(|a| a.sin()));
        out.extend(args.iter().map(|a| a.cos()));
    }
    out
}
