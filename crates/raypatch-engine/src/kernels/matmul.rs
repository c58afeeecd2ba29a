//! Linear layers (`shaders/matmul.wgsl`): a register-tiled matmul with bias, fused activation and an
//! optional in-place residual add.

use crate::kernels::{Activation, MATMUL, MATMUL_F16};
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, View};
use crate::tensor::{padded_cols, Dtype};

/// Rows of `out` one workgroup computes: 64 invocations x 4 rows (`WG * ROWS` in the shader).
const ROWS_PER_GROUP: usize = 256;
/// Columns of `out` one workgroup computes: the shader's 8-column tile of w.
const COLS_PER_GROUP: usize = 8;

/// out = act(x · wᵀ + bias), or out += act(x · wᵀ + bias) when `accumulate` (residual add in place).
///
/// x: `[M, K]` view; w: `[N, K]` tensor (PyTorch `nn.Linear` layout, rows padded with zeros), f32 or f16
/// (f16 weights are widened to f32 as they are loaded; the arithmetic is f32 either way);
/// bias: optional `[1, N]` tensor; out: `[M, N]` view (written with [`Access::Write`], or
/// [`Access::ReadWrite`] when accumulating). The activation is applied before the add. The padding
/// columns of `out` are written as zeros (when accumulating they are zero already and stay zero).
#[allow(clippy::too_many_arguments)]
pub fn linear(
    plan: &mut PlanBuilder,
    label: &str,
    x: View,
    w: TensorId,
    bias: Option<TensorId>,
    out: View,
    act: Activation,
    accumulate: bool,
) {
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
    let [act_code, slope] = act.params();
    let n4 = padded_cols(n) / 4;
    let params = vec![
        m as u32,
        n as u32,
        (padded_cols(k) / 4) as u32,
        n4 as u32,
        act_code,
        slope,
        bias.is_some() as u32,
        accumulate as u32,
        (plan.ld(w) / 4) as u32,
    ];
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
        params,
        bindings: vec![
            (x, Access::Read),
            (plan.all(w), Access::Read),
            (plan.all(bias.unwrap_or(w)), Access::Read),
            (out, out_access),
        ],
        workgroups: grid(groups),
    });
}
