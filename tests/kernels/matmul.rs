//! `linear` on every kernel against the float64 reference: random shapes (tails of the 256x8, 128x128
//! and 8x24 workgroup tiles, several K steps of the tiled ones), every activation, with and without bias,
//! accumulate, row-range views, a layer norm of x's rows first; plus erf accuracy through GELU.

use raypatch_engine::device::KernelChoice;
use raypatch_engine::device::{linear_variant, MatmulKernel};
use raypatch_engine::kernels::matmul::{k_splits, linear, LinearArgs, RowNorm};
use raypatch_engine::kernels::Activation;
use raypatch_engine::kernels::{MATMUL_COOP, MATMUL_COOP_8, MATMUL_COOP_F16, MATMUL_COOP_F16_8};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::{padded_cols, Dtype};
use raypatch_engine::{Gpu, GpuOptions, Precision};
use raypatch_reference::matmul as reference;
use raypatch_reference::norm::layernorm;

use crate::common::*;

struct Case {
    m: usize,
    k: usize,
    n: usize,
    act: Activation,
    bias: bool,
    accumulate: bool,
    /// Run on rows [64, 64 + m) of a bigger x and rows [128, 128 + m) of a bigger out.
    view: bool,
    /// Layer-normalise x's rows first (`LinearArgs::norm`); x's rows then lie around means up to ±4.
    norm: bool,
    /// `Tiled` on a pipeline compiled for this shape, as on GPUs (`KernelChoice::shaped`), rather than the one
    /// pipeline lavapipe's own profile runs for every shape: each shape is a pipeline that llvmpipe takes seconds to
    /// compile from a cold shader cache, so the random shapes take turns and the tile edges are all shaped.
    shaped: bool,
}

const NORM_EPS: f32 = 1e-5;

/// Runs one case and checks the values, the zeroed padding of out, and that rows outside the view of
/// out are untouched.
fn check(case: &Case, rng: &mut Rng) {
    check_with(case, rng, Precision::F32);
}

/// [`check`] at `precision`. f16 weights: the reference uses the f16-rounded weights, since the kernel computes
/// with exactly those in f32. f16 activations (on `Tiled` only, where they apply): the reference also rounds
/// x (normalised, where it is) to f16, and the tolerance adds the f16 sums of each K step.
fn check_with(case: &Case, rng: &mut Rng, precision: Precision) {
    let kernels = if precision == Precision::F16Activations { vec![MatmulKernel::Tiled] } else { matmul_kernels() };
    check_on(case, rng, precision, &kernels);
}

/// [`check_with`] on `kernels`.
fn check_on(case: &Case, rng: &mut Rng, precision: Precision, kernels: &[MatmulKernel]) {
    check_mutated(case, rng, precision, kernels, None);
}

/// [`check_on`], with the op's shader replaced by `mutation` (from, to) of it where given: the check must then
/// fail (the tensor kernels' mutation checks).
fn check_mutated(
    case: &Case,
    rng: &mut Rng,
    precision: Precision,
    kernels: &[MatmulKernel],
    mutation: Option<(&str, &str)>,
) {
    let Case { m, k, n, act, .. } = *case;
    let weights = if precision.f16_weights() { Dtype::F16 } else { Dtype::F32 };
    let f16_activations = precision == Precision::F16Activations;
    let gpu = gpu();
    let (x_start, out_start, extra) = if case.view { (64, 128, 3) } else { (0, 0, 0) };
    let x_rows = x_start + m + extra;
    let out_rows = out_start + m + extra;

    let mut x_all = rng.vec_f32(x_rows * k, -1.0, 1.0);
    if case.norm {
        for row in x_all.chunks_exact_mut(k) {
            let mean = rng.uniform(-4.0, 4.0) as f32;
            row.iter_mut().for_each(|v| *v += mean);
        }
    }
    if kernels == [MatmulKernel::Coop] {
        // The tensor kernels run unchecked: any read of x's rows around the view would turn the output into NaN.
        for (r, row) in x_all.chunks_exact_mut(k).enumerate() {
            if !(x_start..x_start + m).contains(&r) {
                row.fill(f32::NAN);
            }
        }
    }
    let gamma = rng.vec_f32(k, 0.5, 1.5);
    let beta = rng.vec_f32(k, -0.5, 0.5);
    let w = rng.vec_f32(n * k, -1.0, 1.0);
    let bias = case.bias.then(|| rng.vec_f32(n, -1.0, 1.0));
    let residual = case.accumulate.then(|| rng.vec_f32(m * n, -1.0, 1.0));

    // out before the op, padding included: 7 outside the view; in the view the residual (zero padding)
    // when accumulating, else NaN everywhere so that any value or padding the kernel skips shows up.
    let ldo = padded_cols(n);
    let mut out_init = vec![0.0f32; out_rows * ldo];
    for r in 0..out_rows {
        let row = &mut out_init[r * ldo..(r + 1) * ldo];
        if !(out_start..out_start + m).contains(&r) {
            row[..n].fill(7.0);
        } else if let Some(res) = &residual {
            let i = r - out_start;
            row[..n].copy_from_slice(&res[i * n..(i + 1) * n]);
        } else {
            row.fill(f32::NAN);
        }
    }

    let x_t = gpu.upload("x", x_rows, k, &x_all).unwrap();
    let w_t = match weights {
        Dtype::F32 => gpu.upload("w", n, k, &w).unwrap(),
        Dtype::F16 => gpu.upload_f16("w", n, k, &w).unwrap(),
    };
    let w: Vec<f32> = match weights {
        Dtype::F32 => w,
        Dtype::F16 => w.iter().map(|&v| half::f16::from_f32(v).to_f32()).collect(),
    };
    let bias_t = bias.as_ref().map(|b| gpu.upload("bias", 1, n, b).unwrap());
    let gamma_t = gpu.upload("gamma", 1, k, &gamma).unwrap();
    let beta_t = gpu.upload("beta", 1, k, &beta).unwrap();
    let out_t = gpu.upload("out", out_rows, n, &vec![0.0; out_rows * n]).unwrap();
    let out_bytes: Vec<u8> = out_init.iter().flat_map(|v| v.to_le_bytes()).collect();
    let mut x = to_f64(&x_all[x_start * k..(x_start + m) * k]);
    if case.norm {
        x = layernorm(&x, k, &to_f64(&gamma), &to_f64(&beta), f64::from(NORM_EPS));
    }
    // The tensor kernels round x (normalised, where it is) and w to f16 as they stage them: the reference takes
    // the float64 product of the rounded operands.
    let coop = kernels == [MatmulKernel::Coop];
    let x_exact = x.clone();
    if f16_activations || coop {
        x.iter_mut().for_each(|v| *v = half::f16::from_f64(*v).to_f64());
    }
    let mut w64 = to_f64(&w);
    if coop {
        w64.iter_mut().for_each(|v| *v = half::f16::from_f64(*v).to_f64());
    }
    let bias64 = bias.as_ref().map(|b| to_f64(b));
    let residual = residual.map(|r| to_f64(&r));
    let expected = reference::linear(&x, m, k, &w64, n, bias64.as_deref(), act, residual.as_deref());
    let w = w64;
    let bias = bias64;

    for &kernel in kernels {
        gpu.queue.write_buffer(&out_t.buffer, 0, &out_bytes);
        let mut plan = PlanBuilder::new();
        plan.kernels =
            KernelChoice { matmul: kernel, f16_activations, pinned: true, shaped: case.shaped, ..gpu.kernels };
        let x_id = plan.external("x", &x_t);
        let w_id = plan.external("w", &w_t);
        let bias_id = bias_t.as_ref().map(|b| plan.external("bias", b));
        let out_id = plan.external("out", &out_t);
        let x_view = plan.rows_of(x_id, x_start, m);
        let out_view = plan.rows_of(out_id, out_start, m);
        let norm = case.norm.then(|| RowNorm {
            gamma: plan.external("gamma", &gamma_t),
            beta: plan.external("beta", &beta_t),
            eps: NORM_EPS,
        });
        let args = LinearArgs {
            x: x_view,
            weight: w_id,
            bias: bias_id,
            out: out_view,
            act,
            accumulate: case.accumulate,
            norm,
        };
        linear(&mut plan, "linear", args);
        if f16_activations && kernel == MatmulKernel::Tiled {
            assert!(plan.op_kernels().any(|k| k.starts_with("matmul_f16_act")), "f16 activations did not run");
        }
        if kernel == MatmulKernel::Coop {
            assert!(plan.op_kernels().any(|k| k.contains("linear_coop")), "linear_coop did not run");
        }
        if let Some((from, to)) = mutation {
            for shader in [&MATMUL_COOP, &MATMUL_COOP_F16, &MATMUL_COOP_8, &MATMUL_COOP_F16_8] {
                plan.substitute_shader(shader, mutated(shader, from, to));
            }
        }
        run(plan);
        let got = gpu.read_rows(&out_t.buffer, 0, out_rows, ldo).unwrap();

        let what = format!(
            "{kernel:?}: m={m} k={k} n={n} {act:?} bias={} accumulate={} view={} norm={}",
            case.bias, case.accumulate, case.view, case.norm
        );
        let mut values = Vec::with_capacity(m * n);
        for r in 0..out_rows {
            let row = &got[r * ldo..(r + 1) * ldo];
            if (out_start..out_start + m).contains(&r) {
                values.extend_from_slice(&row[..n]);
                assert!(row[n..].iter().all(|&v| v == 0.0), "{what}: padding of out row {r} is {:?}", &row[n..]);
            } else {
                assert_eq!(row, &out_init[r * ldo..(r + 1) * ldo], "{what}: row {r} outside the view changed");
            }
        }

        // f32 accumulation error: a sum of K terms carries relative rounding errors of u = 2^-24 on each
        // partial sum, and those add up like a random walk, so |err| <~ c·√K·u·Σ|x·w| (Higham's probabilistic
        // bound); bias and residual add their own magnitudes, the activations are 1-Lipschitz (GELU 1.13)
        // and GELU's erf error (< 1e-7·|v|/2) is far below the bound.
        // c = 4 (measured c <= 0.72 over these cases); a single wrong product (~Σ|x·w|/K) fails by far.
        let magnitude = (0..m)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .map(|(i, j)| {
                let sum: f64 = (0..k).map(|l| (x[i * k + l] * w[j * k + l]).abs()).sum();
                sum + bias.as_ref().map_or(0.0, |b| b[j].abs()) + residual.as_ref().map_or(0.0, |r| r[i * n + j].abs())
            })
            .fold(0.0, f64::max);
        let u = f64::from(f32::EPSILON / 2.0);
        let mut tol = 4.0 * u * (k as f64).sqrt() * magnitude;
        if case.norm {
            // Each normalised value is off by at most (K/4 + 3)·u·spread/std (kernels::norm::layernorm; the
            // spread of a uniform row is 2√3 std), and a column sums K of them times |w|.
            let normed_err = (k as f64 / 4.0 + 3.0) * u * 2.0 * 3f64.sqrt();
            let w_sum = (0..n).map(|j| w[j * k..(j + 1) * k].iter().map(|v| v.abs()).sum::<f64>()).fold(0.0, f64::max);
            tol += normed_err * w_sum;
        }
        if f16_activations && !coop {
            // x rounded to f16 as it is staged (w is f16 already, in the reference too): each product is off by at
            // most 2^-11 of itself, so a sum by 2^-11·Σ|x·w|; c = 4, as above.
            tol += 4.0 * 2f64.powi(-11) * magnitude;
        }
        if coop && case.norm {
            // The kernel normalises in f32 and then rounds: where its normalised value and the float64 one lie on
            // either side of a rounding boundary, the staged f16 differs by one f16 step (2^-11 relative).
            let flips: f64 = (0..m)
                .flat_map(|i| (0..n).map(move |j| (i, j)))
                .map(|(i, j)| (0..k).map(|l| (x_exact[i * k + l] * w[j * k + l]).abs()).sum::<f64>())
                .fold(0.0, f64::max);
            tol += 2f64.powi(-11) * flips;
        }
        assert_close(&what, &values, &expected, tol, 0.0);
    }
}

const ACTIVATIONS: [Activation; 4] = [Activation::None, Activation::Relu, Activation::LeakyRelu(0.1), Activation::Gelu];

#[test]
fn linear_random_shapes() {
    let mut rng = Rng::new(1);
    // Every combination of activation, bias and accumulate, three times, on random shapes.
    for i in 0..48 {
        let act = match ACTIVATIONS[i % 4] {
            Activation::LeakyRelu(_) => Activation::LeakyRelu(rng.uniform(0.01, 0.3) as f32),
            act => act,
        };
        let case = Case {
            m: rng.range(1, 300),
            k: rng.range(1, 300),
            n: rng.range(1, 200),
            act,
            bias: (i / 4) % 2 == 1,
            accumulate: (i / 8) % 2 == 1,
            view: rng.range(0, 1) == 1,
            norm: i % 3 == 1,
            shaped: i % 3 == 0,
        };
        check(&case, &mut rng);
    }
}

/// The tensor kernels' linear layer (`linear_coop`: f16 cooperative matrices, the adapter's tile), where the device
/// has them (`.ci/coop.sh` runs it on Mesa 26's lavapipe): against the float64 product of the f16-rounded operands,
/// within f32 summation's K-dependent bound; random shapes with tails of its workgroup tiles and K steps, every
/// activation, bias, accumulate, views (rows around them checked untouched), a layer norm first, f32 and f16 weights,
/// and the split K of a few tiles with a deep K.
#[test]
fn linear_coop() {
    if !coop_runs() {
        return;
    }
    let mut rng = Rng::new(6);
    for i in 0..36 {
        let k = if i < 4 {
            [1, 16, 33, 64][i]
        } else if i >= 32 {
            rng.range(1500, 3000)
        } else {
            rng.range(1, 600)
        };
        let case = Case {
            m: rng.range(1, 300),
            k,
            n: rng.range(1, 200),
            act: ACTIVATIONS[i % 4],
            bias: (i / 4) % 2 == 1,
            accumulate: (i / 8) % 2 == 1,
            view: i % 3 == 0,
            norm: i % 5 == 2,
            shaped: false,
        };
        let precision = if i % 2 == 1 { Precision::F16Weights } else { Precision::F32 };
        check_on(&case, &mut rng, precision, &[MatmulKernel::Coop]);
    }
}

/// The mutation check of the tensor kernels' GEMM: `linear_coop` with a wrong fragment index, a skipped K step, a
/// skipped output block or a misplaced row tile must fail `linear_coop`'s check (a test that passes them would
/// pass a broken kernel).
#[test]
fn linear_coop_mutations_fail() {
    if !coop_runs() {
        return;
    }
    let mutations = [
        ("let b1_at = b_base + (sc + CT) * COOP_LD + kk;", "let b1_at = b_base + sc * COOP_LD + kk;"),
        ("if (step + 1u < t.steps) {", "if (step + 2u < t.steps) {"),
        ("coop_emit(t, sr + CT, sc + CT, at, lane);", ""),
        ("return CoopTile((rest % row_tiles) * COOP_BM,", "return CoopTile((rest % row_tiles) * COOP_BN / 2u,"),
    ];
    for (from, to) in mutations {
        let mut rng = Rng::new(7);
        let case = Case {
            m: 150,
            k: 200,
            n: 90,
            act: Activation::None,
            bias: true,
            accumulate: false,
            view: false,
            norm: false,
            shaped: false,
        };
        fails_on_values(&format!("linear_coop with {from:?} replaced by {to:?}"), || {
            check_mutated(&case, &mut rng, Precision::F16Weights, &[MatmulKernel::Coop], Some((from, to)))
        });
    }
}

/// f16 weights (the `matmul_f16` variant), where the adapter has shader-f16: random shapes, every option,
/// and K not a multiple of 8 (f16 rows are padded to 8 halves, so their stride differs from x's).
#[test]
fn linear_f16_weights() {
    if !gpu().features.contains(raypatch_engine::wgpu::Features::SHADER_F16) {
        eprintln!("{} has no shader-f16: f16 weights not tested", gpu().describe());
        return;
    }
    let mut rng = Rng::new(4);
    for i in 0..16 {
        let k = if i < 4 { [1, 4, 5, 9][i] } else { rng.range(1, 300) };
        let case = Case {
            m: rng.range(1, 300),
            k,
            n: rng.range(1, 100),
            act: ACTIVATIONS[i % 4],
            bias: (i / 4) % 2 == 1,
            accumulate: (i / 8) % 2 == 1,
            view: i % 3 == 0,
            norm: false,
            shaped: i % 4 == 0,
        };
        check_with(&case, &mut rng, Precision::F16Weights);
    }
}

/// f16 activations (`Precision::F16Activations`: `linear_tiled` stages x as f16, the products summed in f32), where the adapter has shader-f16: random shapes, every option, a layer norm
/// first (a dispatch of its own here), and K from one vec4 to many steps.
#[test]
fn linear_f16_activations() {
    if !gpu().features.contains(raypatch_engine::wgpu::Features::SHADER_F16) {
        eprintln!("{} has no shader-f16: f16 activations not tested", gpu().describe());
        return;
    }
    let mut rng = Rng::new(5);
    for i in 0..12 {
        let k = if i < 3 { [1, 5, 9][i] } else { rng.range(1, 400) };
        let case = Case {
            m: rng.range(1, 300),
            k,
            n: rng.range(1, 100),
            act: ACTIVATIONS[i % 4],
            bias: (i / 4) % 2 == 1,
            accumulate: i % 5 == 2,
            view: i % 3 == 0,
            norm: i % 4 == 1,
            shaped: i % 3 == 0,
        };
        check_with(&case, &mut rng, Precision::F16Activations);
    }
}

/// Shapes on and just past the edges of the tiles: `Rows`' 256x8 workgroup tile and 4x8 invocation block,
/// `Lanes`' 8x32 row tile, its bands of 64 rows (one workgroup each) and 32-float steps along K (8 texels),
/// `Tiled`'s 128x128 workgroup tile, its 8x8 invocation block and 8-float steps along K.
#[test]
fn linear_tile_edges() {
    let mut rng = Rng::new(3);
    let shapes = [
        (1, 1, 1),
        (256, 4, 8),
        (257, 5, 9),
        (255, 3, 7),
        (4, 8, 12),
        (513, 9, 16),
        (3, 2, 5),
        (8, 32, 24),
        (9, 33, 25),
        (7, 31, 23),
        (16, 64, 48),
        (17, 65, 49),
        (64, 32, 64),
        (65, 33, 65),
        (63, 31, 63),
        (128, 96, 128),
        (129, 7, 129),
        (127, 9, 127),
        (8, 32, 32),
        (72, 8, 33),
        (136, 40, 31),
    ];
    for (i, &(m, k, n)) in shapes.iter().enumerate() {
        let case = Case {
            m,
            k,
            n,
            act: ACTIVATIONS[i % 4],
            bias: i % 2 == 0,
            accumulate: i % 3 == 0,
            view: i % 2 == 1,
            norm: i % 4 == 3,
            shaped: true,
        };
        check(&case, &mut rng);
    }
}

/// `Tiled` splits K among workgroups where the output has too few 128x128 tiles to fill a GPU, and adds the
/// ranges up in a second dispatch; `linear_big_shapes` and the random shapes check the sums.
#[test]
fn linear_tiled_splits_k_when_tiles_are_few() {
    // The official RP-SRT's 300x1536x1536 render layers: 3 x 12 tiles, K cut in 8.
    assert_eq!(k_splits(36, 384), 8);
    // The encoder's 4800x768x2304: 38 x 18 tiles, enough.
    assert_eq!(k_splits(684, 192), 1);
    // Short K is never cut below 32 vec4s a range.
    assert_eq!((k_splits(1, 63), k_splits(1, 64)), (1, 2));
    let gpu = gpu();
    for (m, k, splits) in [(300, 1536, true), (4800, 64, false)] {
        let mut plan = PlanBuilder::new();
        plan.kernels = KernelChoice { matmul: MatmulKernel::Tiled, ..gpu.kernels };
        let x = plan.transient("x", m, k);
        let w = plan.transient("w", 64, k);
        let out = plan.transient("out", m, 64);
        let (x, out) = (plan.all(x), plan.all(out));
        let args = LinearArgs { x, weight: w, bias: None, out, act: Activation::None, accumulate: false, norm: None };
        linear(&mut plan, "linear", args);
        assert_eq!(plan.op_kernels().any(|k| k.ends_with("linear_reduce")), splits, "{m}x{k}");
    }
}

/// On the GPU profile (not pinned), `Tiled` runs every linear layer of 64 columns or more; narrower ones run on
/// `Rows`, whose 8-column tiles waste none, where its grid fills a GPU, and on `Tiled` (K split) where it would be a
/// few long chains.
#[test]
fn tiled_profile_leaves_narrow_outputs_to_rows() {
    let gpu_profile = KernelChoice { matmul: MatmulKernel::Tiled, ..gpu().kernels };
    let variant = |cols, groups| linear_variant(&gpu_profile, cols, groups, true, || false);
    let (tiled, rows) = (MatmulKernel::Tiled, MatmulKernel::Rows);
    assert_eq!((variant(64, 500), variant(63, 500), variant(3, 132)), (tiled, rows, rows));
    assert_eq!((variant(63, 131), variant(3, 2)), (tiled, tiled));
    let pinned = KernelChoice { pinned: true, ..gpu_profile };
    assert_eq!(linear_variant(&pinned, 3, 500, true, || false), tiled);
}

/// The `Rows` grid `linear` measures for that choice: SRT's 4800-row chunks of out_mlp.8 (1536 to 3) and
/// RP-OSRT's mixing dots (300 rows, 6 slots) stay on `Tiled`, with K split; 76800 rows of 3 go to `Rows`.
#[test]
fn narrow_linear_layers_leave_tiled_only_over_many_rows() {
    let gpu_profile = KernelChoice { matmul: MatmulKernel::Tiled, ..gpu().kernels };
    let first_kernel = |m: usize, k: usize, n: usize| {
        let mut plan = PlanBuilder::new();
        plan.kernels = gpu_profile;
        let x = plan.transient("x", m, k);
        let w = plan.transient("w", n, k);
        let out = plan.transient("out", m, n);
        let (x, out) = (plan.all(x), plan.all(out));
        let args = LinearArgs { x, weight: w, bias: None, out, act: Activation::None, accumulate: false, norm: None };
        linear(&mut plan, "linear", args);
        let first = plan.op_kernels().next().expect("one op");
        first
    };
    assert_eq!(first_kernel(4800, 1536, 3), "matmul.linear_tiled");
    assert_eq!(first_kernel(300, 1536, 6), "matmul.linear_tiled");
    assert_eq!(first_kernel(76800, 64, 3), "matmul.linear");
}

#[test]
fn linear_big_shapes() {
    let mut rng = Rng::new(2);
    let cases = [
        Case {
            m: 1000,
            k: 768,
            n: 256,
            act: Activation::Gelu,
            bias: true,
            accumulate: false,
            view: false,
            norm: false,
            shaped: true,
        },
        Case {
            m: 777,
            k: 1536,
            n: 97,
            act: Activation::None,
            bias: true,
            accumulate: true,
            view: true,
            norm: false,
            shaped: true,
        },
        // A transformer layer's pre-norm and to_qkv at the official render's 300 rows (K split on `Tiled`).
        Case {
            m: 300,
            k: 768,
            n: 2304,
            act: Activation::None,
            bias: false,
            accumulate: false,
            view: false,
            norm: true,
            shaped: true,
        },
        // Outputs of many tiles, with K shorter than a step or two.
        Case {
            m: 2000,
            k: 40,
            n: 1100,
            act: Activation::Relu,
            bias: true,
            accumulate: true,
            view: true,
            norm: true,
            shaped: true,
        },
        Case {
            m: 2100,
            k: 70,
            n: 1030,
            act: Activation::Gelu,
            bias: false,
            accumulate: false,
            view: false,
            norm: false,
            shaped: true,
        },
    ];
    for case in &cases {
        check(case, &mut rng);
    }
}

/// erf as the shader computes it, read back through GELU on a dense grid of erf arguments in [-10, 10].
/// For v < 0 the kernel's gelu(v) = (v/2)·(1 + erf(a)) with a = f32(v·(1/√2)), so 2·gelu(v)/v - 1 gives
/// back its erf(a) up to the rounding of 1 + erf and of the product (<= 2^-24 each, relative to 1 + erf);
/// erf(a) for a > 0 is the exact mirror image (the shader evaluates sign(a)·erf(|a|)).
#[test]
fn gelu_erf_accuracy() {
    let gpu = gpu();
    let points = 200_001;
    let v: Vec<f32> = (0..points)
        .map(|i| (-10.0 + 20.0 * i as f64 / (points - 1) as f64) * std::f64::consts::SQRT_2)
        .map(|v| v as f32)
        .collect();
    let x_t = gpu.upload("x", points, 1, &v).unwrap();
    let w_t = gpu.upload("w", 1, 1, &[1.0]).unwrap();
    let mut plan = PlanBuilder::new();
    let x = plan.external("x", &x_t);
    let w = plan.external("w", &w_t);
    let out = plan.output("gelu", points, 1);
    let (x_view, out_view) = (plan.all(x), plan.all(out));
    let args = LinearArgs {
        x: x_view,
        weight: w,
        bias: None,
        out: out_view,
        act: Activation::Gelu,
        accumulate: false,
        norm: None,
    };
    linear(&mut plan, "gelu", args);
    let plan = run(plan);
    let gelu = gpu.read(&plan.tensor(out)).unwrap();

    // erf(a) in float64 from the reference GELU at v = a·√2.
    let erf = |a: f64| {
        let v = a * std::f64::consts::SQRT_2;
        2.0 * raypatch_reference::activation(v, Activation::Gelu) / v - 1.0
    };
    let mut erf_err = 0.0f64;
    for (&v, &g) in v.iter().zip(&gelu) {
        if v < 0.0 {
            let a = f64::from(v * std::f32::consts::FRAC_1_SQRT_2);
            erf_err = erf_err.max((2.0 * f64::from(g) / f64::from(v) - 1.0 - erf(a)).abs());
        }
    }
    eprintln!("erf: max abs error {erf_err:e} over [-10, 10]");
    // The erf approximation is good to ~1e-7 absolute; the read-back adds up to 1.2e-7 of rounding.
    assert!(erf_err < 2e-7, "erf max abs error {erf_err:e}");

    // GELU itself, on both sides: the erf error scaled by |v|/2, plus f32 rounding of the result.
    let expected: Vec<f64> =
        v.iter().map(|&v| raypatch_reference::activation(f64::from(v), Activation::Gelu)).collect();
    for ((&v, &g), &e) in v.iter().zip(&gelu).zip(&expected) {
        let tol = 0.5 * f64::from(v).abs() * 2e-7 + 2.0 * e.abs() * f64::from(f32::EPSILON);
        assert!((f64::from(g) - e).abs() <= tol, "gelu({v}) = {g}, expected {e}");
    }
}

/// A layer's shaped `linear_tiled` pipeline (as on GPUs) serves every row count and K split: the rows, row tiles
/// and splits are params, not override constants, so a render of another size, view count, region or band
/// compiles nothing new. Each result is checked against the float64 reference.
#[test]
fn a_shaped_pipeline_serves_every_row_count() {
    // A GPU of its own: the shared one's counter counts the pipelines other tests compile at the same time.
    let gpu = &Gpu::new(&GpuOptions::default()).expect("no GPU adapter");
    let (k, n) = (512, 40);
    let mut rng = Rng::new(7);
    let mut values = |count: usize| -> Vec<f32> { (0..count).map(|_| rng.uniform(-1.0, 1.0) as f32).collect() };
    let w = values(n * k);
    let w_t = gpu.upload("w", n, k, &w).unwrap();
    let mut compiled = Vec::new();
    // K split in 4 ranges (one row tile), in 3 (100 row tiles) and in 2 (133).
    for (m, splits) in [(3usize, 4), (12_800, 3), (17_000, 2)] {
        assert_eq!(k_splits(m.div_ceil(128) * n.div_ceil(128), k / 4), splits, "m={m}");
        let x = values(m * k);
        let x_t = gpu.upload("x", m, k, &x).unwrap();
        let out_t = gpu.upload("out", m, n, &vec![0.0; m * n]).unwrap();
        let before = gpu.counters().pipelines_compiled;
        let mut plan = PlanBuilder::new();
        plan.kernels = KernelChoice { matmul: MatmulKernel::Tiled, pinned: true, shaped: true, ..gpu.kernels };
        let (x_id, w_id, out_id) = (plan.external("x", &x_t), plan.external("w", &w_t), plan.external("out", &out_t));
        let (x_view, out_view) = (plan.all(x_id), plan.all(out_id));
        let act = Activation::None;
        let args =
            LinearArgs { x: x_view, weight: w_id, bias: None, out: out_view, act, accumulate: false, norm: None };
        linear(&mut plan, "linear", args);
        plan.build(gpu).expect("plan build").execute(gpu);
        compiled.push(gpu.counters().pipelines_compiled - before);
        let got = gpu.read_rows(&out_t.buffer, 0, m, padded_cols(n)).unwrap();
        let got: Vec<f32> = got.chunks(padded_cols(n)).flat_map(|row| row[..n].to_vec()).collect();
        let expected = reference::linear(&to_f64(&x), m, k, &to_f64(&w), n, None, act, None);
        // As in check_with: c·√K·u·Σ|x·w|, with Σ|x·w| <= K for values in [-1, 1].
        let tol = 4.0 * f64::from(f32::EPSILON / 2.0) * (k as f64).sqrt() * k as f64;
        assert_close(&format!("m={m}"), &got, &expected, tol, 0.0);
    }
    assert!(compiled[1..].iter().all(|&c| c == 0), "pipelines compiled per row count: {compiled:?}");
}
