//! Layer normalisation over the columns of each row (`shaders/layernorm.wgsl`).

use super::LAYERNORM;
use crate::device::reduce_rows_per_workgroup;
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, View};

params! {
    /// The uniform of `shaders/layernorm.wgsl`.
    LayerNormParams {
        rows: u32,
        cols: u32,
        /// Row stride in vec4s.
        ld4: u32,
        eps: f32,
    }
}

/// A layer norm's operands: see [`layernorm`].
#[derive(Clone, Copy, Debug)]
pub struct LayerNormArgs {
    pub x: View,
    /// `[1, C]` tensor.
    pub gamma: TensorId,
    /// `[1, C]` tensor.
    pub beta: TensorId,
    pub out: View,
    pub eps: f32,
}

/// Checks a layer norm's `[1, cols]` gamma and beta and its positive eps (`what` names the op in the panic):
/// for [`layernorm`] and for a linear layer that normalises its input (`kernels::matmul::RowNorm`).
pub(crate) fn check_affine(plan: &PlanBuilder, what: &str, cols: usize, gamma: TensorId, beta: TensorId, eps: f32) {
    for (name, t) in [("gamma", gamma), ("beta", beta)] {
        assert!(
            plan.rows(t) == 1 && plan.cols(t) == cols,
            "{what}: {name} is {}x{}, expected 1x{cols}",
            plan.rows(t),
            plan.cols(t)
        );
    }
    assert!(eps > 0.0 && eps.is_finite(), "{what}: eps {eps} must be positive");
}

/// Rows per workgroup of `layernorm`: one invocation per row (`layernorm_wide` and `row_stats` take a
/// workgroup per row).
const ROWS_PER_GROUP: usize = 64;

/// `out[r] = (x[r] - mean(x[r])) / sqrt(var(x[r]) + eps) * gamma + beta` for every row of `x`, as PyTorch's
/// `nn.LayerNorm` over the last dimension (biased variance); `gamma`, `beta`: `[1, C]` tensors, where
/// `C = cols(x) = cols(out)`. Writes every element of `out` (padding zeroed). `eps` must be positive.
///
/// Numerics: a two-pass form on the deviations from the row's first element `x0`, which never rounds the
/// mean to f32 on its own (the output uses `((x - x0) - δ)` with `δ = Σ(x - x0) / C`). Rows far from zero
/// keep the precision of their deviations: with `u = 2^-24`, the error of the normalised value
/// `(x - mean) / sqrt(var + eps)` is at most about `(C/4 + 3) · u · (max(x[r]) - min(x[r])) / std(x[r])`
/// (four partial sums per row; the workgroup-per-row kernels of GPUs add 64 such in a tree) plus its own rounding, so ≤ 1e-3 for any C ≤ 2048 and a spread ≤ 8 std,
/// whatever the row's mean (a row with mean 1e4 and std 1e-2 included), and ~1e-6 on typical rows. A
/// constant row gives exactly `beta`.
///
/// Records no multiply-adds: its work is linear in the data, not multiply-add work worth counting.
pub fn layernorm(plan: &mut PlanBuilder, label: &str, args: LayerNormArgs) {
    let LayerNormArgs { x, gamma, beta, out, eps } = args;
    let cols = plan.cols(x.id);
    assert!(cols > 0, "layernorm {label}: x has no columns");
    assert!(
        plan.cols(out.id) == cols && out.rows == x.rows,
        "layernorm {label}: out is {}x{}, x is {}x{cols}",
        out.rows,
        plan.cols(out.id),
        x.rows
    );
    assert!(x.id != out.id, "layernorm {label}: cannot run in place");
    check_affine(plan, &format!("layernorm {label}"), cols, gamma, beta, eps);
    let params = LayerNormParams { rows: x.rows as u32, cols: cols as u32, ld4: (plan.ld(x.id) / 4) as u32, eps };
    let bindings =
        vec![(x, Access::Read), (plan.all(gamma), Access::Read), (plan.all(beta), Access::Read), (out, Access::Write)];
    let (entry, groups) = if reduce_rows_per_workgroup(&plan.kernels) {
        ("layernorm_wide", x.rows)
    } else {
        ("layernorm", x.rows.div_ceil(ROWS_PER_GROUP))
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &LAYERNORM,
        entry,
        params: params.words(),
        bindings,
        textures: Vec::new(),
        workgroups: grid(groups),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}

/// The statistics of each row of `x` that normalise it as [`layernorm`] does, into `stats` (`[rows(x), 4]`: the
/// row's first element x0, the mean of its deviations from x0, 1 / sqrt(var + eps), 0), a workgroup per row:
/// for `linear_tiled`, which normalises its rows as it stages them (`kernels::matmul::RowNorm`).
pub fn row_stats(plan: &mut PlanBuilder, label: &str, x: View, stats: View, eps: f32) {
    let cols = plan.cols(x.id);
    assert!(cols > 0, "row_stats {label}: x has no columns");
    assert!(
        stats.rows == x.rows && plan.cols(stats.id) == 4,
        "row_stats {label}: stats is {}x{}, expected {}x4",
        stats.rows,
        plan.cols(stats.id),
        x.rows
    );
    let params = LayerNormParams { rows: x.rows as u32, cols: cols as u32, ld4: (plan.ld(x.id) / 4) as u32, eps };
    plan.push(Op {
        label: label.to_string(),
        shader: &LAYERNORM,
        entry: "row_stats",
        params: params.words(),
        // gamma and beta are not read: x again.
        bindings: vec![(x, Access::Read), (x, Access::Read), (x, Access::Read), (stats, Access::Write)],
        textures: Vec::new(),
        workgroups: grid(x.rows),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
