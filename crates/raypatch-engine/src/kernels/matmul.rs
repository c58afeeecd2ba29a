//! Linear layers (`shaders/matmul.wgsl`): a register-tiled matmul with bias, fused activation and an
//! optional in-place residual add.

use crate::kernels::{Activation, MATMUL, MATMUL_F16};
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, View};
use crate::tensor::{padded_cols, Dtype};

/// Rows of `out` one workgroup computes: 64 invocations x 4 rows (`WG * ROWS` in the shader).
const ROWS_PER_GROUP: usize = 256;
/// Columns of `out` one workgroup computes: the shader's 8-column tile of w.
const COLS_PER_GROUP: usize = 8;

params! {
    /// The uniform of `shaders/matmul.wgsl` (and its f16 variant).
    MatmulParams {
        m: u32,
        n: u32,
        /// ld(K) / 4: vec4s per row of x and w.
        k4: u32,
        /// ld(N) / 4: vec4s per row of out.
        n4: u32,
        /// Activation code and slope ([`Activation::params`]).
        act: u32,
        slope: f32,
        has_bias: u32,
        accumulate: u32,
        /// vec4s per row of w: k4 for f32 weights; f16 rows are padded to 8 halves, so k4 or k4 + 1.
        w_ld4: u32,
    }
}

/// A linear layer's operands: see [`linear`].
#[derive(Clone, Copy, Debug)]
pub struct LinearArgs {
    /// `[M, K]` view.
    pub x: View,
    /// `[N, K]` tensor (PyTorch `nn.Linear` layout), f32 or f16.
    pub weight: TensorId,
    /// `[1, N]` tensor.
    pub bias: Option<TensorId>,
    /// `[M, N]` view.
    pub out: View,
    pub act: Activation,
    /// `out += ...` (residual add in place) instead of `out = ...`.
    pub accumulate: bool,
}

/// out = act(x · wᵀ + bias), or out += act(x · wᵀ + bias) when `accumulate` (residual add in place).
///
/// x: `[M, K]` view; w: `[N, K]` tensor (PyTorch `nn.Linear` layout, rows padded with zeros), f32 or f16
/// (f16 weights are widened to f32 as they are loaded; the arithmetic is f32 either way);
/// bias: optional `[1, N]` tensor; out: `[M, N]` view (written with [`Access::Write`], or
/// [`Access::ReadWrite`] when accumulating). The activation is applied before the add. The padding
/// columns of `out` are written as zeros (when accumulating they are zero already and stay zero).
/// Records `M·N·K` multiply-adds.
pub fn linear(plan: &mut PlanBuilder, label: &str, args: LinearArgs) {
    let LinearArgs { x, weight: w, bias, out, act, accumulate } = args;
    let (m, k, n) = (x.rows, plan.cols(x.id), plan.rows(w));
    assert!(k > 0 && n > 0, "linear {label}: empty weight [{n}, {k}]");
    assert_eq!(plan.cols(w), k, "linear {label}: weight is [{n}, {}] but x has {k} columns", plan.cols(w));
    assert!(
        out.rows == m && plan.cols(out.id) == n,
        "linear {label}: out is [{}, {}], expected [{m}, {n}]",
        out.rows,
        plan.cols(out.id)
    );
    if let Some(b) = bias {
        assert!(
            plan.rows(b) == 1 && plan.cols(b) == n,
            "linear {label}: bias is [{}, {}], expected [1, {n}]",
            plan.rows(b),
            plan.cols(b)
        );
    }
    let (act_code, slope) = act.params();
    let n4 = padded_cols(n) / 4;
    let params = MatmulParams {
        m: m as u32,
        n: n as u32,
        k4: (padded_cols(k) / 4) as u32,
        n4: n4 as u32,
        act: act_code,
        slope,
        has_bias: bias.is_some() as u32,
        accumulate: accumulate as u32,
        w_ld4: (plan.ld(w) / 4) as u32,
    };
    assert!(
        plan.dtype(x.id) == Dtype::F32 && bias.is_none_or(|b| plan.dtype(b) == Dtype::F32),
        "linear {label}: x and bias must be f32"
    );
    let shader = match plan.dtype(w) {
        Dtype::F32 => &MATMUL,
        Dtype::F16 => &MATMUL_F16,
    };
    let groups = m.div_ceil(ROWS_PER_GROUP) * padded_cols(n).div_ceil(COLS_PER_GROUP);
    let out_access = if accumulate { Access::ReadWrite } else { Access::Write };
    plan.push(Op {
        label: label.to_string(),
        shader,
        entry: "linear",
        params: params.words(),
        bindings: vec![
            (x, Access::Read),
            (plan.all(w), Access::Read),
            (plan.all(bias.unwrap_or(w)), Access::Read),
            (out, out_access),
        ],
        workgroups: grid(groups),
        multiply_adds: (m as u64) * (n as u64) * (k as u64),
    });
}
