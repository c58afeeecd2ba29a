//! Attention against the float64 reference, on the fused kernel, on flash attention (GPUs' `Tiled`, keys split
//! or not, a query row per invocation or, where the adapter has subgroups, over four lanes) and (where the adapter
//! runs it) on `matmul_lanes`: self-attention from one fused qkv tensor, cross-attention onto a cached kv tensor,
//! separate q/k/v at odd columns, row-range views, and the numerically hard cases (logits of ±1e4, one
//! dominant key, flat rows, 16384 keys).
//!
//! Errors are measured relative to max |v|: the output is a convex combination of the rows of v.

use raypatch_engine::device::{attention_variant, AttentionVariant, KernelChoice, MatmulKernel};
use raypatch_engine::kernels::attention::{attention, flash_splits, AttentionArgs, LANES_SCORES_BYTES};
use raypatch_engine::kernels::{ATTENTION_COOP, ATTENTION_COOP_8};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::padded_cols;
use raypatch_engine::{Gpu, GpuOptions, GpuTensor};
use raypatch_reference as reference;

use crate::common::*;

/// f32 unit roundoff.
const U32: f64 = 1.0 / (1u64 << 24) as f64;
/// Error allowed, times max |v|, with O(1) logits: the f32 logits are off by ~sqrt(dh)·u·|logit|, the weights
/// by as much relatively (plus lavapipe's polynomial exp, ~1e-7), and the f32 sums of weights and weighted
/// v add a few u; the worst seen is 4.4e-7.
const TOL_V: f64 = 2e-6;
/// Fill of the output tensor: rows outside the view must keep it, the row padding must become 0.
const GARBAGE: f32 = 7.5;

/// One input tensor, unpadded row-major.
struct Host {
    rows: usize,
    cols: usize,
    data: Vec<f32>,
}

/// Where q, k or v lives: tensor index, the view's first row, the column of head 0.
#[derive(Clone, Copy, Debug)]
struct Src {
    tensor: usize,
    row: usize,
    col: usize,
}

struct Case {
    tensors: Vec<Host>,
    q: Src,
    k: Src,
    v: Src,
    nq: usize,
    nkv: usize,
    heads: usize,
    dim_head: usize,
    scale: f32,
    /// First row of the output view inside a taller output tensor.
    out_row: usize,
    /// A tensor bound as a constant (a scene's cached kv, `PlanBuilder::constant`): its packings are kept.
    constant: Option<usize>,
}

impl Case {
    fn describe(&self) -> String {
        format!(
            "nq {} nkv {} heads {} dim_head {} scale {} q {:?} k {:?} v {:?} out_row {}",
            self.nq, self.nkv, self.heads, self.dim_head, self.scale, self.q, self.k, self.v, self.out_row
        )
    }

    /// Whether the case runs on `matmul_lanes` when the plan's matmul kernel is `Lanes`: heads a multiple of
    /// 32 wide, columns starting at multiples of 4.
    fn fits_lanes(&self) -> bool {
        self.dim_head.is_multiple_of(32) && [self.q, self.k, self.v].iter().all(|s| s.col.is_multiple_of(4))
    }

    /// Runs attention with the kernel choice `choice`, checks that it zeroed the output row padding and left
    /// the rows around the view alone and that it ran on `matmul_lanes` or flash attention's subgroup variant
    /// where it should, and returns the view's rows (unpadded) and the bytes the plan allocated.
    fn run_gpu(&self, choice: KernelChoice) -> (Vec<f32>, u64) {
        self.run_gpu_mutated(choice, None)
    }

    /// [`run_gpu`](Self::run_gpu), with `attention_coop` replaced by `mutation` (from, to) of it where given.
    fn run_gpu_mutated(&self, choice: KernelChoice, mutation: Option<(&str, &str)>) -> (Vec<f32>, u64) {
        let kernel = choice.matmul;
        let gpu = gpu();
        let inner = self.heads * self.dim_head;
        let ld = padded_cols(inner);
        let out_rows = self.out_row + self.nq + 1;
        let padded_out = gpu.upload("out", out_rows, ld, &vec![GARBAGE; out_rows * ld]).unwrap();
        let out_tensor = GpuTensor { rows: out_rows, cols: inner, ..padded_out.clone() };

        let mut plan = PlanBuilder::new();
        plan.kernels = choice;
        let ids: Vec<_> = self
            .tensors
            .iter()
            .enumerate()
            .map(|(t, h)| {
                let name = format!("in{t}");
                let tensor = gpu.upload(&name, h.rows, h.cols, &h.data).unwrap();
                if self.constant == Some(t) {
                    plan.constant(&name, &tensor)
                } else {
                    plan.external(&name, &tensor)
                }
            })
            .collect();
        let out_id = plan.external("out", &out_tensor);
        let q = plan.rows_of(ids[self.q.tensor], self.q.row, self.nq);
        let k = plan.rows_of(ids[self.k.tensor], self.k.row, self.nkv);
        let v = plan.rows_of(ids[self.v.tensor], self.v.row, self.nkv);
        let out = plan.rows_of(out_id, self.out_row, self.nq);
        let args = AttentionArgs {
            q,
            q_col: self.q.col,
            k,
            k_col: self.k.col,
            v,
            v_col: self.v.col,
            out,
            heads: self.heads,
            dim_head: self.dim_head,
            scale: self.scale,
        };
        attention(&mut plan, "attn", args);
        let on_lanes = plan.op_kernels().any(|k| k == "matmul_lanes.gemm");
        assert_eq!(on_lanes, kernel == MatmulKernel::Lanes && self.fits_lanes(), "{kernel:?}: {}", self.describe());
        let on_flash = plan.op_kernels().any(|k| k.starts_with("attention_flash") && k.ends_with(".flash"));
        // The tensor kernels' attention where the device's choice says (heads whose tiles fit its workgroup memory).
        let coop_fits =
            matches!(attention_variant(&choice, self.nq, self.dim_head, || None::<()>), AttentionVariant::Coop(_));
        let on_coop = plan.op_kernels().any(|k| k.ends_with(".attention_coop"));
        assert_eq!(on_coop, kernel == MatmulKernel::Coop && coop_fits, "{kernel:?}: {}", self.describe());
        if let Some((from, to)) = mutation {
            for shader in [&ATTENTION_COOP, &ATTENTION_COOP_8] {
                plan.substitute_shader(shader, mutated(shader, from, to));
            }
        }
        let flash_expected = kernel == MatmulKernel::Tiled || (kernel == MatmulKernel::Coop && !coop_fits);
        assert_eq!(on_flash, flash_expected, "{kernel:?}: {}", self.describe());
        let on_subgroups = plan.op_kernels().any(|k| k.starts_with("attention_flash_lanes"));
        assert_eq!(on_subgroups, on_flash && choice.subgroups, "{choice:?}: {}", self.describe());
        let plan = run(plan);
        // A constant kv tensor bound whole has its keys and values packed outside the plan, once.
        let kept = self.constant.is_some_and(|t| self.k.tensor == t && self.v.tensor == t && self.kv_whole());
        let kv_packs = plan.op_labels().filter(|l| l.ends_with(".pack_k") || l.ends_with(".pack_v")).count();
        assert_eq!(kv_packs, if on_lanes && !kept { 2 } else { 0 }, "{kernel:?}: {}", self.describe());

        let padded = gpu.read(&padded_out).unwrap();
        let mut result = Vec::with_capacity(self.nq * inner);
        for (r, row) in padded.chunks(ld).enumerate() {
            if (self.out_row..self.out_row + self.nq).contains(&r) {
                result.extend_from_slice(&row[..inner]);
                assert!(row[inner..].iter().all(|&x| x == 0.0), "{}: row {r} padding not zeroed", self.describe());
            } else {
                assert!(row.iter().all(|&x| x == GARBAGE), "{}: row {r} outside the view written", self.describe());
            }
        }
        (result, plan.peak_bytes())
    }

    /// Whether the keys and values are all the rows of their tensors.
    fn kv_whole(&self) -> bool {
        [self.k, self.v].iter().all(|s| s.row == 0 && self.tensors[s.tensor].rows == self.nkv)
    }

    /// The view's rows of a tensor as f64, with the tensor's column count.
    fn slice(&self, src: Src, rows: usize) -> (Vec<f64>, usize) {
        let h = &self.tensors[src.tensor];
        (h.data[src.row * h.cols..(src.row + rows) * h.cols].iter().map(|&x| x as f64).collect(), h.cols)
    }

    fn reference(&self) -> Vec<f64> {
        let (q, q_ld) = self.slice(self.q, self.nq);
        let (k, k_ld) = self.slice(self.k, self.nkv);
        let (v, v_ld) = self.slice(self.v, self.nkv);
        reference::attention::attention(
            &q,
            q_ld,
            self.q.col,
            &k,
            k_ld,
            self.k.col,
            &v,
            v_ld,
            self.v.col,
            self.nq,
            self.nkv,
            self.heads,
            self.dim_head,
            self.scale as f64,
        )
    }

    /// The head columns of every row of `src`'s tensor from the view's first row on, for editing inputs.
    fn heads_mut(&mut self, src: Src) -> impl Iterator<Item = &mut [f32]> {
        let inner = self.heads * self.dim_head;
        let h = &mut self.tensors[src.tensor];
        h.data.chunks_mut(h.cols).skip(src.row).map(move |row| &mut row[src.col..src.col + inner])
    }

    /// max |v| over the values the heads read.
    fn v_max(&self) -> f64 {
        let (v, v_ld) = self.slice(self.v, self.nkv);
        let cols = self.v.col..self.v.col + self.heads * self.dim_head;
        v.chunks(v_ld).flat_map(|row| &row[cols.clone()]).fold(0.0, |m, x| m.max(x.abs()))
    }

    /// Per (query, head), the error the f32 rounding of the logits can cause, times max |v|.
    ///
    /// The kernel's logit s_j (scale folded into q, a dh-term dot product, minus the running max) is off by
    /// at most D = (dh + 4)·u·max_j Σ_d |scale·q_d·k_jd|. That scales each softmax weight w_j by a factor in
    /// [e^-2D, e^2D]; the weights off the top key move by at most (e^2D - 1)(1 - w_max) in total and the top
    /// one by as much, so the output moves by at most 2(e^2D - 1)(1 - w_max)·max |v|.
    fn logit_rounding_bounds(&self) -> Vec<f64> {
        let (q, q_ld) = self.slice(self.q, self.nq);
        let (k, k_ld) = self.slice(self.k, self.nkv);
        let (dh, scale) = (self.dim_head, self.scale as f64);
        let mut bounds = Vec::with_capacity(self.nq * self.heads);
        for qi in q.chunks(q_ld) {
            for h in 0..self.heads {
                let qh = &qi[self.q.col + h * dh..][..dh];
                let (mut logits, mut worst) = (Vec::with_capacity(self.nkv), 0.0f64);
                for kj in k.chunks(k_ld) {
                    let kh = &kj[self.k.col + h * dh..][..dh];
                    logits.push(scale * qh.iter().zip(kh).map(|(a, b)| a * b).sum::<f64>());
                    worst = worst.max(scale.abs() * qh.iter().zip(kh).map(|(a, b)| (a * b).abs()).sum::<f64>());
                }
                let max = logits.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let w_max = 1.0 / logits.iter().map(|s| (s - max).exp()).sum::<f64>();
                let d = (dh + 4) as f64 * U32 * worst;
                bounds.push(2.0 * (2.0 * d).exp_m1() * (1.0 - w_max));
            }
        }
        bounds
    }

    /// Checks attention on every kernel against the reference within (TOL_V + extra[i*heads + h])·max |v|
    /// per (query, head).
    fn check_within(&self, extra: &[f64]) {
        let want = self.reference();
        let v_max = self.v_max();
        let dh = self.dim_head;
        for choice in attention_choices() {
            let kernel = (choice.matmul, choice.subgroups);
            let (got, _) = self.run_gpu(choice);
            for (n, (&g, &w)) in got.iter().zip(&want).enumerate() {
                let (i, h) = (n / (self.heads * dh), n % (self.heads * dh) / dh);
                let tol = (TOL_V + extra[i * self.heads + h]) * v_max;
                assert!(
                    (g as f64 - w).abs() <= tol,
                    "{kernel:?}: {}: out[{i}, head {h}, {}] = {g:e}, reference {w:e}, tolerance {tol:e}",
                    self.describe(),
                    n % dh
                );
            }
        }
    }

    fn check(&self) {
        self.check_within(&vec![0.0; self.nq * self.heads]);
    }

    /// The case with q, k and v rounded to f16, as the tensor kernels stage them.
    fn rounded_to_f16(&self) -> Case {
        let tensors = self
            .tensors
            .iter()
            .map(|h| Host { data: h.data.iter().map(|&x| half::f16::from_f32(x).to_f32()).collect(), ..*h })
            .collect();
        Case { tensors, ..*self }
    }

    /// Checks the tensor kernels' attention (`attention_coop`, with `mutation` of it where given) against the
    /// float64 attention of the f16-rounded q, k and v: within TOL_V·max |v|, plus the rounding of the softmax
    /// weights P to f16 for the second product (each off by 2^-11 of itself, so the output by 2^-11·max |v|).
    fn check_coop(&self, mutation: Option<(&str, &str)>) {
        let want = self.rounded_to_f16().reference();
        let (got, _) =
            self.run_gpu_mutated(KernelChoice { matmul: MatmulKernel::Coop, pinned: true, ..gpu().kernels }, mutation);
        let tol = (TOL_V + 2f64.powi(-11)) * self.v_max();
        assert_close(&format!("Coop: {}", self.describe()), &got, &want, tol, 0.0);
    }
}

/// The kernel choices attention runs differently on: `Rows` (the fused kernel), `Tiled` (flash attention, as on
/// GPUs) a query row per invocation and, where the adapter has subgroups that suit, over four lanes, and
/// `Lanes` where the adapter has it.
fn attention_choices() -> Vec<KernelChoice> {
    let gpu = gpu();
    let subgroups = KernelChoice::subgroups_suit(&gpu.info, gpu.features);
    if !subgroups {
        eprintln!("flash attention's subgroup variant not tested on {}: no subgroups of 4+ lanes", gpu.describe());
    }
    let choice = |matmul, subgroups| KernelChoice { matmul, subgroups, ..gpu.kernels };
    let mut choices: Vec<_> = matmul_kernels().into_iter().map(|kernel| choice(kernel, false)).collect();
    if subgroups {
        choices.push(choice(MatmulKernel::Tiled, true));
    }
    choices
}

/// The choice of `kernel` without subgroup variants.
fn plain(kernel: MatmulKernel) -> KernelChoice {
    KernelChoice { matmul: kernel, subgroups: false, ..gpu().kernels }
}

/// How q, k and v are laid out.
#[derive(Clone, Copy, Debug)]
enum Layout {
    /// One fused qkv tensor `[n, c0 + 3*inner + extra]`, one row range for q, k and v.
    FusedQkv,
    /// q `[nq, c0 + inner + extra]` and a cached kv tensor `[nkv, 2*inner + extra]`.
    CachedKv,
    /// Three tensors, each with its heads at a random column.
    Separate,
}

/// A random case: every view starts at row 0, 64 or 128 of a taller tensor; columns start at random
/// offsets, unaligned unless heads are a multiple of 32 wide (then multiples of 4, so that the case runs on
/// `matmul_lanes` too); q, k and v are uniform in [-2, 2] (logits of a few units with scale dh^-0.5), the
/// columns no head uses are NaN.
fn random_case(rng: &mut Rng, layout: Layout, nq: usize, nkv: usize, heads: usize, dim_head: usize) -> Case {
    let inner = heads * dim_head;
    let step = if dim_head.is_multiple_of(32) { 4 } else { 1 };
    let mut tensors = Vec::new();
    // A tensor whose view has `rows` rows and `cols` used columns, with 0-2 rows and columns more.
    let mut add = |rng: &mut Rng, rows: usize, cols: usize| -> Src {
        let row = 64 * rng.range(0, 2);
        let (total_rows, total_cols) = (row + rows + rng.range(0, 2), cols + rng.range(0, 2));
        tensors.push(Host {
            rows: total_rows,
            cols: total_cols,
            data: rng.vec_f32(total_rows * total_cols, -2.0, 2.0),
        });
        Src { tensor: tensors.len() - 1, row, col: 0 }
    };
    let (q, k, v) = match layout {
        Layout::FusedQkv => {
            let c0 = step * rng.range(0, 3);
            let src = add(rng, nq, c0 + 3 * inner);
            (Src { col: c0, ..src }, Src { col: c0 + inner, ..src }, Src { col: c0 + 2 * inner, ..src })
        }
        Layout::CachedKv => {
            let c0 = step * rng.range(0, 3);
            let q = add(rng, nq, c0 + inner);
            let kv = add(rng, nkv, 2 * inner);
            (Src { col: c0, ..q }, kv, Src { col: inner, ..kv })
        }
        Layout::Separate => {
            let mut one = |rng: &mut Rng, rows: usize| {
                let c0 = step * rng.range(0, 5);
                Src { col: c0, ..add(rng, rows, c0 + inner) }
            };
            (one(rng, nq), one(rng, nkv), one(rng, nkv))
        }
    };
    // The columns around the heads are other data the kernel must not use: make them NaN.
    for (t, h) in tensors.iter_mut().enumerate() {
        let used: Vec<_> = [q, k, v].into_iter().filter(|s| s.tensor == t).map(|s| s.col..s.col + inner).collect();
        for row in h.data.chunks_mut(h.cols) {
            for (c, x) in row.iter_mut().enumerate() {
                if !used.iter().any(|r| r.contains(&c)) {
                    *x = f32::NAN;
                }
            }
        }
    }
    let out_row = 64 * rng.range(0, 1);
    let scale = (dim_head as f32).powf(-0.5);
    Case { tensors, q, k, v, nq, nkv, heads, dim_head, scale, out_row, constant: None }
}

#[test]
fn attention_random_shapes() {
    let mut rng = Rng::new(0xA77E);
    let layouts = [Layout::FusedQkv, Layout::CachedKv, Layout::Separate];
    let dim_heads = [1, 3, 5, 8, 15, 16, 32, 64, 128];
    for (n, &dim_head) in dim_heads.iter().cycle().take(27).enumerate() {
        let layout = layouts[n % 3];
        let heads = rng.range(1, 6);
        // At most ~2e7 multiply-adds per case, so the file stays fast on lavapipe.
        let budget = 20_000_000 / (heads * dim_head);
        let (nq, nkv) = match layout {
            Layout::FusedQkv => {
                let n = rng.range(1, 300.min(budget.isqrt()));
                (n, n)
            }
            _ => {
                let nq = rng.range(1, 300.min(budget));
                (nq, rng.range(1, 500.min(budget / nq)))
            }
        };
        random_case(&mut rng, layout, nq, nkv, heads, dim_head).check();
    }
}

/// Logits up to ~±1e4 from integer q and k (|x| <= 16) and a power-of-two scale: every product and partial
/// sum is an integer below 2^24, so the f32 logits are exact and this tests the softmax itself (overflow
/// would give inf or NaN) at the normal tolerance.
#[test]
fn attention_large_exact_logits() {
    let mut rng = Rng::new(0x1E4);
    for (layout, nq, nkv, heads, dim_head) in [(Layout::FusedQkv, 70, 70, 2, 64), (Layout::CachedKv, 33, 257, 3, 15)] {
        let mut case = random_case(&mut rng, layout, nq, nkv, heads, dim_head);
        for h in case.tensors.iter_mut() {
            h.data.iter_mut().for_each(|x| *x = (*x * 8.0).round());
        }
        case.scale = 2.0;
        case.check();
    }
}

/// Logits up to ~±1e4 from arbitrary f32 q and k: the f32 logit itself is off by up to D ~ 0.1 here, so the
/// tolerance adds `logit_rounding_bounds` (which vanishes where one key takes all the weight).
#[test]
fn attention_large_random_logits() {
    let mut rng = Rng::new(0xB16);
    let mut case = random_case(&mut rng, Layout::Separate, 60, 90, 2, 64);
    case.scale = 300.0;
    case.check_within(&case.logit_rounding_bounds());
}

/// One key's logit exceeds all others by > 70 (their weights < e^-70), and flat rows where all logits are
/// equal (q = 0, or identical keys with large logits): the output is that key's v, or the mean of v, to
/// f32 rounding.
#[test]
fn attention_dominant_key_and_flat_rows() {
    let mut rng = Rng::new(0xD0);
    let (nq, nkv, heads, dim_head) = (40, 300, 2, 8);
    let inner = heads * dim_head;

    // Every query is `direction`; key 123 is 40·direction (logit >= 80), the others are tiny (|logit| < 0.2).
    let mut dominant = random_case(&mut rng, Layout::Separate, nq, nkv, heads, dim_head);
    let direction: Vec<f32> = rng.vec_f32(inner, 0.5, 1.0);
    dominant.heads_mut(dominant.q).for_each(|row| row.copy_from_slice(&direction));
    for (j, key) in dominant.heads_mut(dominant.k).enumerate() {
        if j == 123 {
            key.iter_mut().zip(&direction).for_each(|(x, d)| *x = 40.0 * d);
        } else {
            key.iter_mut().for_each(|x| *x *= 0.01);
        }
    }
    dominant.scale = 1.0;
    dominant.check();

    let mut zero_q = random_case(&mut rng, Layout::CachedKv, nq, nkv, heads, dim_head);
    zero_q.heads_mut(zero_q.q).for_each(|row| row.fill(0.0));
    zero_q.check();

    let mut same_k = random_case(&mut rng, Layout::Separate, nq, nkv, heads, dim_head);
    let first = same_k.heads_mut(same_k.k).next().unwrap().to_vec();
    same_k.heads_mut(same_k.k).for_each(|row| row.copy_from_slice(&first));
    same_k.scale = 50.0;
    same_k.check();
}

/// 16384 keys for a few queries; the fused kernel's plan allocates nothing that grows with nq·nkv (only its
/// params block: the tensors are external).
#[test]
fn attention_long_kv() {
    let mut rng = Rng::new(0x4000);
    let case = random_case(&mut rng, Layout::CachedKv, 5, 16384, 2, 64);
    let (_, peak_bytes) = case.run_gpu(plain(MatmulKernel::Rows));
    assert!(peak_bytes <= 256, "attention plan allocated {peak_bytes} bytes");
    case.check();
}

/// Flash attention (`Tiled`, as on GPUs) splits the keys among workgroups when query tiles x heads are too
/// few to fill a GPU, down to one key tile a split, and merges the splits; with enough query tiles it runs
/// one dispatch. Both match the reference, including splits whose last tile is partly past the keys.
#[test]
fn flash_attention_splits_keys_when_queries_are_few() {
    // RP-SRT k=8 at 120x160: 300 queries (5 tiles), 12 heads of 64 (32-key tiles), 300 keys: 10 splits of 32.
    assert_eq!(flash_splits(5, 12, 300, 32), (32, 10));
    // A full-resolution SRT render: 19200 queries, 300 tiles a head, one split.
    assert_eq!(flash_splits(300, 12, 300, 32), (300usize.div_ceil(32) * 32, 1));
    // Few keys: never more splits than key tiles.
    assert_eq!(flash_splits(1, 1, 5, 64), (64, 1));
    let mut rng = Rng::new(0xF1A5);
    for (nq, nkv, heads, dim_head, splits) in
        [(300, 300, 12, 64, true), (77, 1000, 3, 20, true), (4096, 40, 16, 8, false)]
    {
        let case = random_case(&mut rng, Layout::CachedKv, nq, nkv, heads, dim_head);
        let mut plan = PlanBuilder::new();
        plan.kernels = KernelChoice { matmul: MatmulKernel::Tiled, ..gpu().kernels };
        let q = plan.transient("q", nq, heads * dim_head);
        let kv = plan.transient("kv", nkv, 2 * heads * dim_head);
        let out = plan.transient("out", nq, heads * dim_head);
        let (q, kv, out) = (plan.all(q), plan.all(kv), plan.all(out));
        let scale = 0.125;
        let inner = heads * dim_head;
        attention(
            &mut plan,
            "attn",
            AttentionArgs { q, q_col: 0, k: kv, k_col: 0, v: kv, v_col: inner, out, heads, dim_head, scale },
        );
        assert_eq!(plan.op_kernels().any(|k| k.ends_with(".combine")), splits, "{nq}x{nkv}, {heads} heads");
        case.check();
    }
}

/// On `matmul_lanes` the scores of 300 queries x 8192 keys x 4 heads (38 MiB) exceed what one pass holds:
/// the queries go in three passes (128 + 128 + 44 rows). The plan holds one pass's scores and their packed
/// softmax, the keys and values packed (4 MiB each) and the queries packed.
#[test]
fn attention_lanes_query_passes() {
    let mut rng = Rng::new(0x4002);
    let case = random_case(&mut rng, Layout::CachedKv, 300, 8192, 4, 32);
    if matmul_kernels().contains(&MatmulKernel::Lanes) {
        let (_, peak_bytes) = case.run_gpu(plain(MatmulKernel::Lanes));
        let bound = 2 * LANES_SCORES_BYTES as u64 + (9 << 20);
        assert!(peak_bytes <= bound, "attention plan allocated {peak_bytes} bytes, more than {bound}");
    }
    case.check();
}

/// 16384 keys with exact logits up to ~±1e4 (integer q and k as in `attention_large_exact_logits`), and 16384
/// keys with a flat row (q = 0: the output is the mean of v).
#[test]
fn attention_long_kv_large_logits() {
    let mut rng = Rng::new(0x4001);
    let mut large = random_case(&mut rng, Layout::CachedKv, 9, 16384, 2, 64);
    for h in large.tensors.iter_mut() {
        h.data.iter_mut().for_each(|x| *x = (*x * 8.0).round());
    }
    large.scale = 2.0;
    large.check();

    let mut flat = random_case(&mut rng, Layout::CachedKv, 9, 16384, 2, 64);
    flat.heads_mut(flat.q).for_each(|row| row.fill(0.0));
    flat.check();
}

#[test]
#[should_panic(expected = "output must have heads*dim_head")]
fn attention_rejects_wrong_output_width() {
    let mut plan = PlanBuilder::new();
    let qkv = plan.input("qkv", 10, 3 * 16);
    let out = plan.output("out", 10, 15);
    let (qkv, out) = (plan.all(qkv), plan.all(out));
    let (q, k, v) = (qkv, qkv, qkv);
    let args = AttentionArgs { q, q_col: 0, k, k_col: 16, v, v_col: 32, out, heads: 2, dim_head: 8, scale: 0.35 };
    attention(&mut plan, "attn", args);
}

/// Cross-attention onto a scene's cached kv tensor bound as a constant (`PlanBuilder::constant`, as renders
/// bind a scene's keys and values): on `matmul_lanes` its keys and (transposed) values are packed outside
/// the plan and kept with the tensor, so a second plan on the same tensor packs nothing and makes no texture
/// for them; the results are the reference's. A view of part of a constant tensor is packed per plan.
#[test]
fn attention_kept_scene_keys_values() {
    let mut rng = Rng::new(0x5CE2);
    let mut case = random_case(&mut rng, Layout::CachedKv, 70, 45, 2, 64);
    let kv = case.k.tensor;
    let h = &case.tensors[kv];
    let start = case.k.row * h.cols;
    case.tensors[kv] = Host { rows: 45, cols: h.cols, data: h.data[start..start + 45 * h.cols].to_vec() };
    (case.k.row, case.v.row) = (0, 0);
    case.constant = Some(kv);
    assert!(case.kv_whole());
    case.check();

    // Two plans on one constant kv tensor: the first makes scratch texture 0 and the two kept packings, the
    // second only its scratch texture, and both give the same output.
    if matmul_kernels().contains(&MatmulKernel::Lanes) {
        // A GPU of its own: the textures counter of the shared one counts the other tests' textures too.
        let gpu = &Gpu::new(&GpuOptions::default()).expect("no GPU adapter");
        let host = &case.tensors[kv];
        let kv_tensor = gpu.upload("kv", host.rows, host.cols, &host.data).unwrap();
        let q_host = &case.tensors[case.q.tensor];
        let q_tensor = gpu.upload("q", q_host.rows, q_host.cols, &q_host.data).unwrap();
        let inner = case.heads * case.dim_head;
        let render = || {
            let out_tensor = gpu.upload("out", case.nq, inner, &vec![0.0; case.nq * inner]).unwrap();
            let mut plan = PlanBuilder::new();
            plan.kernels = KernelChoice { matmul: MatmulKernel::Lanes, ..gpu.kernels };
            let (q, kv, out) =
                (plan.external("q", &q_tensor), plan.constant("kv", &kv_tensor), plan.external("out", &out_tensor));
            let args = AttentionArgs {
                q: plan.rows_of(q, case.q.row, case.nq),
                q_col: case.q.col,
                k: plan.all(kv),
                k_col: 0,
                v: plan.all(kv),
                v_col: inner,
                out: plan.all(out),
                heads: case.heads,
                dim_head: case.dim_head,
                scale: case.scale,
            };
            attention(&mut plan, "attn", args);
            let before = gpu.counters().textures_created;
            plan.build(gpu).expect("plan build").execute(gpu);
            (gpu.counters().textures_created - before, gpu.read(&out_tensor).unwrap())
        };
        let (first_textures, first) = render();
        let (second_textures, second) = render();
        assert_eq!((first_textures, second_textures), (3, 1), "textures made by the first and second plan");
        assert_eq!(first, second);
    }
}

/// The tensor kernels' attention (`attention_coop`: Q·Kᵀ and P·V on f16 cooperative matrices, the online softmax in
/// f32), where the device has them (`.ci/coop.sh`): every layout, heads from 1 to 128 floats wide (padded to whole
/// output blocks), queries past a tile's edge, keys past a block's edge and split across workgroups.
#[test]
fn attention_coop() {
    if !coop_runs() {
        return;
    }
    let mut rng = Rng::new(0xC00B);
    let layouts = [Layout::FusedQkv, Layout::CachedKv, Layout::Separate];
    for (n, &dim_head) in [1, 5, 16, 31, 32, 64, 100, 128].iter().cycle().take(16).enumerate() {
        let heads = rng.range(1, 4);
        let budget = 20_000_000 / (heads * dim_head);
        let nq = rng.range(1, 300.min(budget));
        let nkv = if n % 3 == 0 { nq } else { rng.range(1, 700.min(budget / nq)) };
        let layout = if nkv == nq { layouts[n % 3] } else { layouts[1 + n % 2] };
        random_case(&mut rng, layout, nq, nkv, heads, dim_head).check_coop(None);
    }
}

/// The mutation check of `attention_coop`: a wrong key-fragment index, a skipped key block or a skipped output
/// block must fail its check.
#[test]
fn attention_coop_mutations_fail() {
    if !coop_runs() {
        return;
    }
    let mutations = [
        ("let k_at = sg * CT * QK_LD + d0;", "let k_at = d0;"),
        ("base < key_end; base += BC)", "base < key_end; base += 2u * BC)"),
        ("let f = fi * COOP_SUBGROUPS + sg;", "let f = fi * COOP_SUBGROUPS;"),
    ];
    for (from, to) in mutations {
        // Enough query tiles and keys that each of the splits (flash_splits) walks several key blocks, with 8x8 and
        // with 16x16 tiles.
        let case = random_case(&mut Rng::new(9), Layout::CachedKv, 512, 2000, 4, 64);
        fails_on_values(&format!("attention_coop with {from:?} replaced by {to:?}"), || {
            case.check_coop(Some((from, to)))
        });
    }
}
