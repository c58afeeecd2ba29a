//! Fourier positional encoding against the float64 reference, and its multipliers against torch.

use raypatch_engine::kernels::posenc::{fourier_encode, multipliers, FourierArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::padded_cols;
use raypatch_engine::GpuTensor;
use raypatch_reference::posenc as reference;

use crate::common::*;

const SENTINEL: f32 = -9.5;

/// Absolute error of sin/cos of the f32 argument: the range reduction is exact up to two roundings of the
/// reduced argument (≤ 6e-8), the polynomials add ≤ 6e-8 and the output rounding ≤ 3e-8. The kernel states
/// 1.2e-7 for |argument| ≤ 2^20 (≤ 1e-7 measured on lavapipe); 2e-7 (3.4 ulp of 1) leaves a margin for
/// other compilers' fusions.
const TOL: f64 = 2e-7;

/// Where the encoding goes: rows `[start, start + rows)` of a `[total, cols]` tensor, columns from `col`.
struct OutLayout {
    total: usize,
    start: usize,
    rows: usize,
    cols: usize,
    col: usize,
}

/// Encodes `coords` (`[R, 3]`, bound as rows from `coords_start` of a tensor whose earlier rows are junk)
/// into an output prefilled with SENTINEL (padding included), checks that
/// nothing outside the encoded columns of the view's rows was written (except the row padding, zeroed
/// when the encoding ends the row), and returns the encoded `[rows, 6N]` block.
fn encode(
    coords: &[f32],
    coords_start: usize,
    repeat: usize,
    first_row: usize,
    m: &[f32],
    out: &OutLayout,
) -> Vec<f32> {
    let gpu = gpu();
    let ld = padded_cols(out.cols);
    let width = 6 * m.len();
    let coord_rows = coords.len() / 3;
    let junk_then_coords: Vec<f32> = std::iter::repeat_n(1e6, coords_start * 3).chain(coords.iter().copied()).collect();
    let coords = gpu.upload("coords", coords_start + coord_rows, 3, &junk_then_coords).unwrap();
    let out_t = gpu.upload("out", out.total, ld, &vec![SENTINEL; out.total * ld]).unwrap();
    let out_t = GpuTensor { cols: out.cols, ..out_t };
    let mut b = PlanBuilder::new();
    let (ci, oi) = (b.external("coords", &coords), b.external("out", &out_t));
    let (cv, ov) = (b.rows_of(ci, coords_start, coord_rows), b.rows_of(oi, out.start, out.rows));
    let args = FourierArgs { coords: cv, repeat, first_row, multipliers: m, out: ov, col: out.col };
    fourier_encode(&mut b, "posenc", args);
    run(b);
    let padded = gpu.read_rows(&out_t.buffer, 0, out.total, ld).unwrap();
    let ends_row = out.col + width == out.cols;
    let mut got = Vec::with_capacity(out.rows * width);
    for (r, row) in padded.chunks(ld).enumerate() {
        let in_view = (out.start..out.start + out.rows).contains(&r);
        for (j, &v) in row.iter().enumerate() {
            if in_view && (out.col..out.col + width).contains(&j) {
                got.push(v);
            } else {
                let want = if in_view && ends_row && j >= out.cols { 0.0 } else { SENTINEL };
                assert_eq!(
                    v,
                    want,
                    "row {r} column {j} (view rows {}.., columns {}..{})",
                    out.start,
                    out.col,
                    out.col + width
                );
            }
        }
    }
    got
}

/// The whole `[rows, 6N]` output.
fn plain(rows: usize, n: usize) -> OutLayout {
    OutLayout { total: rows, start: 0, rows, cols: 6 * n, col: 0 }
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&v| v as f64).collect()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn multipliers_match_torch() {
    // (2 ** torch.arange(-5, 15, dtype=torch.float32)) * math.pi
    let arange: [u32; 20] = [
        0x3dc90fdb, 0x3e490fdb, 0x3ec90fdb, 0x3f490fdb, 0x3fc90fdb, 0x40490fdb, 0x40c90fdb, 0x41490fdb, 0x41c90fdb,
        0x42490fdb, 0x42c90fdb, 0x43490fdb, 0x43c90fdb, 0x44490fdb, 0x44c90fdb, 0x45490fdb, 0x45c90fdb, 0x46490fdb,
        0x46c90fdb, 0x47490fdb,
    ];
    assert_eq!(bits(&multipliers(20, -5.0, None)), arange);
    // torch.linspace(start, end, n, dtype=torch.float32) * math.pi, from torch 2.x on the CPU.
    let linspace: [(usize, f64, f64, &[u32]); 5] = [
        (7, 0.0, 8.0, &[0x00000000, 0x40860a92, 0x41060a92, 0x41490fdb, 0x41860a91, 0x41a78d36, 0x41c90fdb]),
        (
            20,
            -5.0,
            14.0,
            &[
                0xc17b53d2, 0xc1490fdb, 0xc116cbe4, 0xc0c90fdb, 0xc0490fdb, 0x00000000, 0x40490fdb, 0x40c90fdb,
                0x4116cbe4, 0x41490fdb, 0x417b53d2, 0x4196cbe4, 0x41afede0, 0x41c90fdb, 0x41e231d6, 0x41fb53d2,
                0x420a3ae7, 0x4216cbe4, 0x42235ce2, 0x422fede0,
            ],
        ),
        (
            32,
            0.001,
            9.7,
            &[
                0x3b4de32f, 0x3f7c6e14, 0x3ffc0723, 0x403ceb9e, 0x407bd3ab, 0x409d5ddb, 0x40bcd1e1, 0x40dc45e7,
                0x40fbb9ed, 0x410d96fa, 0x411d50fd, 0x412d0b00, 0x413cc503, 0x414c7f06, 0x415c3909, 0x416bf30c,
                0x417bad11, 0x4185b38a, 0x418d908c, 0x41956d8d, 0x419d4a8f, 0x41a52790, 0x41ad0492, 0x41b4e193,
                0x41bcbe94, 0x41c49b96, 0x41cc7898, 0x41d45599, 0x41dc329b, 0x41e40f9c, 0x41ebec9e, 0x41f3c9a0,
            ],
        ),
        (
            13,
            2.0,
            -3.0,
            &[
                0x40c90fdb, 0x409f2c8e, 0x406a9281, 0x4016cbe4, 0x3f860a93, 0xbe860a8d, 0xbfc90fdd, 0xc0384e8a,
                0xc0860a92, 0xc0afede0, 0xc0d9d12e, 0xc101da3d, 0xc116cbe4,
            ],
        ),
        (1, 2.5, 9.0, &[0x40fb53d2]),
    ];
    for (n, start, end, want) in linspace {
        assert_eq!(bits(&multipliers(n, start, Some(end))), want, "linspace({start}, {end}, {n})");
    }
}

/// Every octave from -5 to 14 on coordinates up to |10|: arguments up to 10 · 2^14 · π ≈ 5.1e5.
#[test]
fn fourier_encode_every_octave() {
    let mut rng = Rng::new(21);
    let m = multipliers(20, -5.0, None);
    let rows = 4096;
    let mut coords = vec![10.0, -10.0, 9.999999, -9.999999, 1.0, -1.0];
    coords.extend(rng.vec_f32(rows * 3 - coords.len(), -10.0, 10.0));
    let got = encode(&coords, 0, 1, 0, &m, &plain(rows, m.len()));
    let want = reference::fourier_encode(&f64s(&coords), 1, 0, rows, &m);
    assert_close("octaves -5..14, |c| <= 10", &got, &want, TOL, 0.0);
}

/// A dense sweep of the argument over [-2e5, 2e5] (multiplier 1), and the f32 values nearest to every
/// multiple of π/2 there with their neighbours, where the reduction cancels the most.
#[test]
fn fourier_encode_dense_argument_sweep() {
    let mut rng = Rng::new(22);
    let limit = 2e5f64;
    let mut coords = Vec::new();
    for k in 0..=(limit / std::f64::consts::FRAC_PI_2) as u32 {
        let nearest = ((k as f64 * std::f64::consts::FRAC_PI_2) as f32).to_bits();
        let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
        coords.extend([nearest.saturating_sub(1), nearest, nearest + 1].map(|b| sign * f32::from_bits(b)));
    }
    let sweep = 3 << 16;
    coords.extend((0..sweep).map(|i| (-limit + 2.0 * limit * (i as f64 + rng.unit()) / sweep as f64) as f32));
    let rows = coords.len() / 3;
    let got = encode(&coords, 0, 1, 0, &[1.0], &plain(rows, 1));
    let want = reference::fourier_encode(&f64s(&coords), 1, 0, rows, &[1.0]);
    assert_close("arguments in [-2e5, 2e5]", &got, &want, TOL, 0.0);
}

/// Random multiplier counts and forms (octaves -5..=14), `repeat` broadcasting from a mid-tensor `first_row`, a column
/// offset inside a wider output, and row-range views of both tensors; one large case.
#[test]
fn fourier_encode_broadcast_columns_and_views() {
    let mut rng = Rng::new(23);
    for case in 0..12 {
        // Octaves within -5..=14 (the accurate range); up to the 32 multipliers an op takes in linspace form.
        let m = if case == 0 {
            multipliers(4, 0.0, None)
        } else if rng.range(0, 1) == 0 {
            let n = rng.range(1, 20);
            multipliers(n, rng.range(0, 20 - n) as f64 - 5.0, None)
        } else {
            multipliers(rng.range(1, 32), rng.uniform(-5.0, 1.0), Some(rng.uniform(2.0, 14.0)))
        };
        let n = m.len();
        let (coord_rows, repeat) = if case == 0 { (300, 1000) } else { (rng.range(1, 40), rng.range(1, 50)) };
        let rows = if case == 0 { 300_000 } else { rng.range(1, coord_rows * repeat) };
        let first_row = rng.range(0, coord_rows * repeat - rows);
        let col = if case == 0 { 0 } else { rng.range(0, 9) };
        let extra = if rng.range(0, 1) == 0 { 0 } else { rng.range(1, 7) };
        let start = 64 * rng.range(0, 2);
        let out = OutLayout { total: start + rows + rng.range(0, 30), start, rows, cols: col + 6 * n + extra, col };
        let coords = rng.vec_f32(coord_rows * 3, -10.0, 10.0);
        let got = encode(&coords, 64 * rng.range(0, 2), repeat, first_row, &m, &out);
        let want = reference::fourier_encode(&f64s(&coords), repeat, first_row, rows, &m);
        let what = format!("N {n}, {rows} rows from {first_row} with repeat {repeat}, columns {col}.. of {}", out.cols);
        assert_close(&what, &got, &want, TOL, 0.0);
    }
}

/// Camera positions up to 1e3 away (stress suite): the position octaves -5..9 of the official configs make
/// arguments up to 1e3 · 2^9 · π ≈ 1.6e6, above the 2^20 up to which the kernel states 1.2e-7: there
/// round(a·2/π) may be off by one more, so the polynomials see |r| up to ~0.95. Measured 1.2e-7 still,
/// within the same tolerance.
#[test]
fn fourier_encode_far_camera_positions() {
    let mut rng = Rng::new(24);
    let m = multipliers(15, -5.0, None);
    let rows = 8192;
    let mut coords = vec![1000.0, -1000.0, 999.9999, -999.9999, 0.0, 1e-3];
    coords.extend(rng.vec_f32(rows * 3 - coords.len(), -1000.0, 1000.0));
    let got = encode(&coords, 0, 1, 0, &m, &plain(rows, m.len()));
    let want = reference::fourier_encode(&f64s(&coords), 1, 0, rows, &m);
    assert_close("octaves -5..9, |c| <= 1e3", &got, &want, TOL, 0.0);
}
