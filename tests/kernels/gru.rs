//! The GRU cell's gates against the float64 reference.

use raypatch_engine::kernels::gru::{gru_cell, GruArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_reference::gru as reference;

use crate::common::*;

const SENTINEL: f32 = 5.875;
/// f32 unit roundoff.
const U: f64 = 1.0 / (1u64 << 24) as f64;

/// One case: gi and gh `[*, 3·dim]` and h `[*, dim]` (unpadded), each read from its own first row.
struct Case {
    dim: usize,
    rows: usize,
    gi: Vec<f32>,
    gi_start: usize,
    gh: Vec<f32>,
    gh_start: usize,
    h: Vec<f32>,
    h_start: usize,
    out_start: usize,
}

impl Case {
    fn random(rng: &mut Rng, dim: usize, rows: usize, gates: f64, state: f64) -> Case {
        let mut start = || 64 * rng.range(0, 2);
        let (gi_start, gh_start, h_start, out_start) = (start(), start(), start(), start());
        let mut tall = |first: usize, cols: usize, range: f64| {
            let total = first + rows + rng.range(0, 5);
            rng.vec_f32(total * cols, -range, range)
        };
        let gi = tall(gi_start, 3 * dim, gates);
        let gh = tall(gh_start, 3 * dim, gates);
        let h = tall(h_start, dim, state);
        Case { dim, rows, gi, gi_start, gh, gh_start, h, h_start, out_start }
    }

    fn describe(&self) -> String {
        format!(
            "gru {}x{} from rows gi {} gh {} h {} out {}",
            self.rows, self.dim, self.gi_start, self.gh_start, self.h_start, self.out_start
        )
    }

    /// Runs the kernel into rows from `out_start` of an output prefilled with SENTINEL (padding included),
    /// checks that the view's padding is zero and every other row untouched, and returns the view's rows.
    fn run_gpu(&self) -> Vec<f32> {
        let gpu = gpu();
        let (dim, rows) = (self.dim, self.rows);
        let gi = gpu.upload("gi", self.gi.len() / (3 * dim), 3 * dim, &self.gi).unwrap();
        let gh = gpu.upload("gh", self.gh.len() / (3 * dim), 3 * dim, &self.gh).unwrap();
        let h = gpu.upload("h", self.h.len() / dim, dim, &self.h).unwrap();
        let out = sentinel_tensor(self.out_start + rows + 3, dim, SENTINEL);
        let mut b = PlanBuilder::new();
        let ids = [b.external("gi", &gi), b.external("gh", &gh), b.external("h", &h), b.external("out", &out)];
        let starts = [self.gi_start, self.gh_start, self.h_start, self.out_start];
        let [gi, gh, h, out_view] = std::array::from_fn(|i| b.rows_of(ids[i], starts[i], rows));
        gru_cell(&mut b, "gru", GruArgs { gi, gh, h, out: out_view });
        run(b);
        read_written_rows(&out, self.out_start..self.out_start + rows, SENTINEL)
    }

    fn reference(&self) -> Vec<f64> {
        let (dim, rows) = (self.dim, self.rows);
        let gates = |v: &[f32], start: usize| to_f64(&v[start * 3 * dim..(start + rows) * 3 * dim]);
        reference::gru_cell(
            &gates(&self.gi, self.gi_start),
            &gates(&self.gh, self.gh_start),
            &to_f64(&self.h[self.h_start * dim..(self.h_start + rows) * dim]),
            dim,
        )
    }

    /// Error allowed per element, from the f64 values of the gates (see `bound`).
    fn bounds(&self) -> Vec<f64> {
        let (dim, rows) = (self.dim, self.rows);
        let mut out = Vec::with_capacity(rows * dim);
        for row in 0..rows {
            let gi = &self.gi[(self.gi_start + row) * 3 * dim..][..3 * dim];
            let gh = &self.gh[(self.gh_start + row) * 3 * dim..][..3 * dim];
            let h = &self.h[(self.h_start + row) * dim..][..dim];
            for j in 0..dim {
                let at = |v: &[f32], gate: usize| f64::from(v[gate * dim + j]);
                out.push(bound([at(gi, 0), at(gi, 1), at(gi, 2)], [at(gh, 0), at(gh, 1), at(gh, 2)], h[j] as f64));
            }
        }
        out
    }

    /// Checks the kernel against the reference element by element; returns the max error and the largest
    /// error as a fraction of its element's bound.
    fn check(&self) -> (f64, f64) {
        let got = self.run_gpu();
        let want = self.reference();
        let (mut max_abs, mut max_frac) = (0.0f64, 0.0f64);
        for (i, ((&g, &w), b)) in got.iter().zip(&want).zip(self.bounds()).enumerate() {
            let err = if g.is_finite() { (g as f64 - w).abs() } else { f64::INFINITY };
            assert!(err <= b, "{}: element {i} is {g:e}, want {w:e} (bound {b:e})", self.describe());
            max_abs = max_abs.max(err);
            max_frac = max_frac.max(err / b);
        }
        (max_abs, max_frac)
    }
}

/// Relative error of the kernels' f32 exp at x: (2|x| + 8)·u, as `tests/kernels/elementwise.rs` allows
/// (WGSL's 3 + 2|x| ulp).
fn exp_rel(x: f64) -> f64 {
    U * (2.0 * x.abs() + 8.0)
}

/// Absolute error of `tanh_stable` on an exact argument v: exp's relative error δ = exp_rel(2v) on
/// e = exp(−2|v|) moves (1 − e) / (1 + e) by 2e·δ/(1 + e)² ≤ 2e·(4|v| + 8)·u ≤ 10u (e·|v| ≤ 0.19), the
/// rounding of −2|v| and the three operations a few u more, and the series below |v| = 0.25 is within 1e-8
/// relative.
const TANH_ABS: f64 = 16.0 * U;

fn sigmoid(s: f64) -> f64 {
    1.0 / (1.0 + (-s).exp())
}

/// Absolute error of the shader's sigmoid at the f32 sum `s` of two f32 gate inputs: the sum rounds
/// (u·|s|, times σ'(s) ≤ σ(−|s|)), exp(−|s|) is off by exp_rel(s) relatively, which moves the result by at
/// most σ(−|s|)·exp_rel(s), and the division and product round once or twice (2u of the result).
fn sigmoid_error(s: f64) -> f64 {
    let tail = sigmoid(-s.abs());
    tail * (exp_rel(s) + U * s.abs() + 2.0 * U) + 2.0 * U * sigmoid(s)
}

/// The error of the GRU cell's f32 output at one element, by propagating the errors of its steps from
/// the exact gates: r's error reaches n's argument a = gi_n + r·gh_n times |gh_n|, a's own roundings add
/// u·(|r·gh_n| + |a|), a's error is scaled by tanh'(a) = 1 − n², tanh adds TANH_ABS; out = (h − n)·z + n
/// takes z's error times |h − n| and n's times (1 − z), and rounds three times (u of each partial result).
/// The whole is doubled for first-order terms left out.
fn bound(gi: [f64; 3], gh: [f64; 3], h: f64) -> f64 {
    let (sr, sz) = (gi[0] + gh[0], gi[1] + gh[1]);
    let (r, z) = (sigmoid(sr), sigmoid(sz));
    let a = gi[2] + r * gh[2];
    let n = a.tanh();
    let a_err = gh[2].abs() * sigmoid_error(sr) + U * ((r * gh[2]).abs() + a.abs());
    let n_err = (1.0 - n * n) * a_err + TANH_ABS;
    let out = (h - n) * z + n;
    let rounding = U * ((h - n).abs() * (1.0 + z) + out.abs());
    2.0 * (sigmoid_error(sz) * (h - n).abs() + n_err * (1.0 - z) + rounding)
}

/// Dims including ones that are not multiples of 4 (3·dim then is not either), views at row offsets.
#[test]
fn gru_cell_random_shapes_and_views() {
    let mut rng = Rng::new(71);
    let (mut worst_abs, mut worst_frac) = (0.0f64, 0.0f64);
    let mut dims = vec![1, 2, 3, 4, 5, 7, 64, 65, 130];
    dims.extend((0..5).map(|_| rng.range(1, 300)));
    for dim in dims {
        let rows = rng.range(1, 40);
        let (gates, state) = (rng.uniform(0.5, 6.0), rng.uniform(0.5, 3.0));
        let case = Case::random(&mut rng, dim, rows, gates, state);
        let (abs, frac) = case.check();
        (worst_abs, worst_frac) = (worst_abs.max(abs), worst_frac.max(frac));
    }
    eprintln!("gru random: max abs error {worst_abs:e}, max fraction of the bound {worst_frac:.3}");
}

/// Gate inputs of ±100 and beyond, where a tanh written as (e^2v − 1) / (e^2v + 1) gives inf / inf = NaN
/// past |v| ≈ 44, and every combination of saturated r, z and n; also arguments near tanh_stable's switch
/// at |v| = 0.25 and tiny ones where tanh's relative accuracy matters.
#[test]
fn gru_cell_extreme_gates() {
    let mut rng = Rng::new(72);
    let values = [0.0f32, 1e-6, 0.2, 0.2499, 0.25, 0.2501, 1.0, 9.0, 44.0, 45.0, 88.0, 100.0, 1e4];
    let extremes: Vec<f32> = values.iter().flat_map(|&v| [v, -v]).collect();
    let pick = |rng: &mut Rng| extremes[rng.range(0, extremes.len() - 1)];
    for (dim, rows) in [(5, 70), (7, 9), (13, 3)] {
        let mut case = Case::random(&mut rng, dim, rows, 1.0, 2.0);
        for v in case.gi.iter_mut().chain(case.gh.iter_mut()) {
            *v = pick(&mut rng);
        }
        // The gh of n multiplies r: keep it moderate in some rows so that r·gh_n does not always saturate n.
        let gates = case.gh.len() / (3 * dim);
        for r in (0..gates).step_by(2) {
            for j in 2 * dim..3 * dim {
                case.gh[r * 3 * dim + j] = rng.uniform(-1.0, 1.0) as f32;
            }
        }
        let (abs, frac) = case.check();
        eprintln!("gru extreme {rows}x{dim}: max abs error {abs:e}, max fraction of the bound {frac:.3}");
    }
}
