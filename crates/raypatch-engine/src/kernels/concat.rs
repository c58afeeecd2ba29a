//! Column concatenation (`shaders/concat.wgsl`): `torch.cat((a, b), -1)`, the OSRT render MLP's input
//! `cat(slot mix, queries)`.

use super::CONCAT;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

params! {
    /// The uniform of `shaders/concat.wgsl`.
    ConcatParams {
        rows: u32,
        a_cols: u32,
        /// Floats per row of a.
        a_ld: u32,
        b_cols: u32,
        /// Floats per row of b.
        b_ld: u32,
        /// Floats per row of out.
        out_ld: u32,
    }
}

/// Invocations per workgroup: one per element of the output.
const GROUP_SIZE: usize = 64;

/// `out[r, :] = cat(a[r, :], b[r, :])` for views of equal rows; `out` has `cols(a) + cols(b)` columns. Writes
/// every element of `out` (padding zero). Records no multiply-adds (a copy).
pub fn concat_columns(plan: &mut PlanBuilder, label: &str, a: View, b: View, out: View) {
    let (a_cols, b_cols) = (plan.cols(a.id), plan.cols(b.id));
    assert!(
        a.rows == b.rows && out.rows == a.rows && plan.cols(out.id) == a_cols + b_cols,
        "concat_columns {label}: a {}x{a_cols} and b {}x{b_cols} into out {}x{}",
        a.rows,
        b.rows,
        out.rows,
        plan.cols(out.id)
    );
    let out_ld = plan.ld(out.id);
    let params = ConcatParams {
        rows: a.rows as u32,
        a_cols: a_cols as u32,
        a_ld: plan.ld(a.id) as u32,
        b_cols: b_cols as u32,
        b_ld: plan.ld(b.id) as u32,
        out_ld: out_ld as u32,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &CONCAT,
        entry: "concat_columns",
        params: params.words(),
        bindings: vec![(a, Access::Read), (b, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid((a.rows * out_ld).div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
