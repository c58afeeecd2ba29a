//! LayerNorm against the float64 reference, on both kernels: an invocation per row (CPU adapters) and a
//! workgroup per row (GPUs: `device::reduce_rows_per_workgroup`).

use std::ops::Range;

use raypatch_engine::device::{KernelChoice, MatmulKernel};
use raypatch_engine::kernels::norm::{layernorm, LayerNormArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::GpuTensor;
use raypatch_reference::norm as reference;

use crate::common::*;

const SENTINEL: f32 = 7.25;
/// PyTorch's default.
const EPS: f32 = 1e-5;

/// The two ways a layer norm runs: the plan's kernel family that picks each (`device::reduce_rows_per_workgroup`).
const KERNELS: [MatmulKernel; 2] = [MatmulKernel::Rows, MatmulKernel::Tiled];

/// Runs `layernorm` as `kernel`'s family does on rows `x_rows` of `x` into as many rows from `out_start` of an
/// `out_total`-row output (`out`: (out_total, out_start)) prefilled with SENTINEL (padding included). Checks that
/// the view's padding is zero and every other row untouched; returns the view's rows, unpadded.
fn run_layernorm(
    kernel: MatmulKernel,
    x: &GpuTensor,
    x_rows: Range<usize>,
    (gamma, beta, eps): (&[f32], &[f32], f32),
    (out_total, out_start): (usize, usize),
) -> Vec<f32> {
    let gpu = gpu();
    let (cols, rows) = (x.cols, x_rows.len());
    let out = sentinel_tensor(out_total, cols, SENTINEL);
    let gamma = gpu.upload("gamma", 1, cols, gamma).unwrap();
    let beta = gpu.upload("beta", 1, cols, beta).unwrap();
    let mut b = PlanBuilder::new();
    b.kernels = KernelChoice { matmul: kernel, ..gpu.kernels };
    let (xi, gi, bi, oi) =
        (b.external("x", x), b.external("gamma", &gamma), b.external("beta", &beta), b.external("out", &out));
    let (xv, ov) = (b.rows_of(xi, x_rows.start, rows), b.rows_of(oi, out_start, rows));
    layernorm(&mut b, "ln", LayerNormArgs { x: xv, gamma: gi, beta: bi, out: ov, eps });
    run(b);
    read_written_rows(&out, out_start..out_start + rows, SENTINEL)
}

fn normals(rng: &mut Rng, n: usize, mean: f64, std: f64) -> Vec<f32> {
    (0..n).map(|_| (mean + std * rng.normal()) as f32).collect()
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&v| v as f64).collect()
}

#[test]
fn layernorm_random_shapes_and_views() {
    let gpu = gpu();
    let mut rng = Rng::new(11);
    let mut widths = vec![1, 2, 3, 4, 5, 7, 8, 63, 64, 65, 768, 2048];
    widths.extend((0..8).map(|_| rng.range(1, 2048)));
    for cols in widths {
        let rows = rng.range(1, 150);
        let (x_start, out_start) = (64 * rng.range(0, 2), 64 * rng.range(0, 2));
        let x_rows = x_start + rows + rng.range(0, 40);
        let out_rows = out_start + rows + rng.range(0, 40);
        let (mean, std) = (rng.uniform(-3.0, 3.0), rng.uniform(-4.0, 4.0).exp());
        let x = normals(&mut rng, x_rows * cols, mean, std);
        let gamma = normals(&mut rng, cols, 1.0, 0.5);
        let beta = normals(&mut rng, cols, 0.0, 1.0);
        let eps = [EPS, 1e-6, 1e-3][rng.range(0, 2)];
        let xt = gpu.upload("x", x_rows, cols, &x).unwrap();
        let want = reference::layernorm(
            &f64s(&x[x_start * cols..(x_start + rows) * cols]),
            cols,
            &f64s(&gamma),
            &f64s(&beta),
            eps as f64,
        );
        for kernel in KERNELS {
            let got = run_layernorm(kernel, &xt, x_start..x_start + rows, (&gamma, &beta, eps), (out_rows, out_start));
            // The normalised values are within ~√C·u of exact on random rows (f32 sums of C/4 terms); times
            // |gamma| ≤ 3 and plus beta: 2e-6 absolute plus 2e-6 of the output's scale leaves a 5x margin.
            let case = format!("{kernel:?}: {rows}x{cols} from rows {x_start}/{out_start}, eps {eps}");
            assert_close(&case, &got, &want, 2e-6, 2e-6);
        }
    }
}

/// Rows far from zero: mean ±1e4 and std 1e-2, where an f32 mean is off by 5% of the std by rounding alone.
#[test]
fn layernorm_large_mean_small_spread() {
    let gpu = gpu();
    let mut rng = Rng::new(12);
    for (cols, mean) in [(2048, 1e4), (768, -1e4), (37, 1e4), (5, 1e4), (1000, 3e4)] {
        let rows = 64;
        let x = normals(&mut rng, rows * cols, mean, 1e-2);
        let (ones, zeros) = (vec![1.0; cols], vec![0.0; cols]);
        let xt = gpu.upload("x", rows, cols, &x).unwrap();
        let want = reference::layernorm(&f64s(&x), cols, &vec![1.0; cols], &vec![0.0; cols], EPS as f64);
        // The kernel's error bound for the normalised value is (C/4 + 3)·u·(max - min)/std per row (see
        // `layernorm`); taken with the widest spread over the rows, plus 4 ulp of the largest value.
        let u = 2f64.powi(-24);
        let bound = x
            .chunks(cols)
            .zip(want.chunks(cols))
            .map(|(xr, nr)| {
                let xr = f64s(xr);
                let m = xr.iter().sum::<f64>() / cols as f64;
                let std = (xr.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / cols as f64).sqrt();
                let spread = xr.iter().cloned().fold(f64::MIN, f64::max) - xr.iter().cloned().fold(f64::MAX, f64::min);
                let top = nr.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                (cols as f64 / 4.0 + 3.0) * u * spread / std.max(1e-30) + 4.0 * u * top
            })
            .fold(0.0, f64::max);
        assert!(bound < 1e-3, "{cols} columns: bound {bound:e} above the 1e-3 that `layernorm` states");
        for kernel in KERNELS {
            let got = run_layernorm(kernel, &xt, 0..rows, (&ones, &zeros, EPS), (rows, 0));
            assert_close(&format!("{kernel:?}: {cols} columns around {mean}"), &got, &want, bound, 0.0);
        }
    }
}

/// Constant rows have zero variance: the output is exactly beta, never NaN (also with a huge constant).
#[test]
fn layernorm_constant_rows_give_beta() {
    let gpu = gpu();
    let mut rng = Rng::new(13);
    for cols in [1, 3, 4, 6, 256, 2047] {
        let constants = [0.0f32, 1e4, -3.5, 1e-30, -1e30, 7.0];
        let mut x = Vec::new();
        for &c in &constants {
            x.extend(std::iter::repeat_n(c, cols));
        }
        let gamma = normals(&mut rng, cols, 0.0, 2.0);
        let beta = normals(&mut rng, cols, 0.0, 2.0);
        let rows = constants.len();
        let xt = gpu.upload("x", rows, cols, &x).unwrap();
        for kernel in KERNELS {
            let got = run_layernorm(kernel, &xt, 0..rows, (&gamma, &beta, EPS), (rows, 0));
            for (r, row) in got.chunks(cols).enumerate() {
                assert_eq!(row, &beta[..], "{kernel:?}: {cols} columns: constant row {} is not beta", constants[r]);
            }
        }
    }
}

/// The row count of a full-resolution decoder pass: the dispatch covers every row (a workgroup per row: more
/// than 65535 workgroups, so the grid spills into y).
#[test]
fn layernorm_many_rows() {
    let gpu = gpu();
    let mut rng = Rng::new(14);
    for (kernel, rows) in [(MatmulKernel::Rows, 1_200_000), (MatmulKernel::Tiled, 70_000)] {
        let cols = 3;
        let x = rng.vec_f32(rows * cols, -2.0, 2.0);
        let gamma = normals(&mut rng, cols, 1.0, 0.5);
        let beta = normals(&mut rng, cols, 0.0, 1.0);
        let xt = gpu.upload("x", rows, cols, &x).unwrap();
        let got = run_layernorm(kernel, &xt, 0..rows, (&gamma, &beta, EPS), (rows, 0));
        let want = reference::layernorm(&f64s(&x), cols, &f64s(&gamma), &f64s(&beta), EPS as f64);
        // As in the random-shape test; 3 columns only, but rows with nearly equal values get large outputs.
        assert_close(&format!("{kernel:?}: {rows} rows"), &got, &want, 2e-6, 2e-6);
    }
}
