//! Rows mixed by weights (`shaders/mix.wgsl`): `out = w · x`, the official OSRT mixing block's slot mix
//! `Σ_s w·slots` and slot attention's `updates = attn · v`.

use super::MIX;
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, View};

params! {
    /// The uniform of `shaders/mix.wgsl`.
    MixParams {
        rows: u32,
        n: u32,
        /// Floats per row of w.
        w_ld: u32,
        /// vec4s per row of x and out.
        ld4: u32,
    }
}

/// A mix's operands: see [`mix_rows`].
#[derive(Clone, Copy, Debug)]
pub struct MixArgs {
    /// `[rows, n]` view: the weights.
    pub w: View,
    /// `[n, cols]` tensor: the rows mixed.
    pub x: TensorId,
    /// `[rows, cols]` view.
    pub out: View,
}

/// Invocations per workgroup: one per vec4 of the output.
const GROUP_SIZE: usize = 64;

/// `out[r, :] = Σ_i w[r, i] · x[i, :]`, summed over `i` in order. Writes every element of `out` (padding
/// zero). Records `rows · n · cols` multiply-adds.
pub fn mix_rows(plan: &mut PlanBuilder, label: &str, args: MixArgs) {
    let MixArgs { w, x, out } = args;
    let (n, cols) = (plan.cols(w.id), plan.cols(x));
    assert!(n > 0 && cols > 0, "mix_rows {label}: empty operand");
    assert_eq!(plan.rows(x), n, "mix_rows {label}: x has {} rows, w has {n} columns", plan.rows(x));
    assert!(
        out.rows == w.rows && plan.cols(out.id) == cols,
        "mix_rows {label}: out is {}x{}, expected {}x{cols}",
        out.rows,
        plan.cols(out.id),
        w.rows
    );
    let ld4 = plan.ld(x) / 4;
    let params = MixParams { rows: w.rows as u32, n: n as u32, w_ld: plan.ld(w.id) as u32, ld4: ld4 as u32 };
    plan.push(Op {
        label: label.to_string(),
        shader: &MIX,
        entry: "mix_rows",
        params: params.words(),
        bindings: vec![(w, Access::Read), (plan.all(x), Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid((w.rows * ld4).div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: (w.rows * n * cols) as u64,
    });
}
