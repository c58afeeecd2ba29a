//! Softmax and normalisation along one axis of a matrix (`shaders/softmax.wgsl`): the attention weights of
//! slot attention (over slots, then renormalised over inputs) and of the OSRT mixing block (over slots).

use super::SOFTMAX;
use crate::device::reduce_rows_per_workgroup;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

params! {
    /// The uniform of `shaders/softmax.wgsl`.
    SoftmaxParams {
        rows: u32,
        cols: u32,
        /// Floats per row of x and out.
        ld: u32,
        scale: f32,
        eps: f32,
    }
}

/// The axis a [`softmax`] runs along.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// Along each row (over the columns).
    Rows,
    /// Along each column (over the rows).
    Columns,
}

/// A softmax's operands: see [`softmax`].
#[derive(Clone, Copy, Debug)]
pub struct SoftmaxArgs {
    /// `[rows, cols]` view.
    pub x: View,
    /// `[rows, cols]` view of another tensor.
    pub out: View,
    pub axis: Axis,
    /// The logits are `scale · x`.
    pub scale: f32,
    /// Added to every probability (the official slot attention's 1e-8; 0 elsewhere).
    pub eps: f32,
}

/// Invocations per workgroup: one per row or column (`softmax_rows_wide` takes a workgroup per row).
const GROUP_SIZE: usize = 64;

/// `out = softmax(scale · x) + eps` along `axis` (PyTorch's `(x * scale).softmax(dim) + eps`, max-subtracted).
/// Writes every element of `out`, padding zeroed. Records no multiply-adds (elementwise work).
pub fn softmax(plan: &mut PlanBuilder, label: &str, args: SoftmaxArgs) {
    let SoftmaxArgs { x, out, axis, scale, eps } = args;
    let (entry, groups) = match axis {
        Axis::Rows if reduce_rows_per_workgroup(&plan.kernels) => ("softmax_rows_wide", x.rows),
        Axis::Rows => ("softmax_rows", x.rows.div_ceil(GROUP_SIZE)),
        Axis::Columns => ("softmax_columns", plan.ld(x.id).div_ceil(GROUP_SIZE)),
    };
    record(plan, label, entry, x, out, scale, eps, groups);
}

/// `out[r, :] = x[r, :] / Σ x[r, :]` for every row (the official slot attention's renormalisation over
/// inputs). Writes every element of `out`, padding zeroed.
pub fn normalize_rows(plan: &mut PlanBuilder, label: &str, x: View, out: View) {
    record(plan, label, "normalize_rows", x, out, 1.0, 0.0, x.rows.div_ceil(GROUP_SIZE));
}

#[allow(clippy::too_many_arguments)]
fn record(
    plan: &mut PlanBuilder,
    label: &str,
    entry: &'static str,
    x: View,
    out: View,
    scale: f32,
    eps: f32,
    groups: usize,
) {
    let cols = plan.cols(x.id);
    assert!(cols > 0 && x.rows > 0, "{entry} {label}: empty x");
    assert!(
        plan.cols(out.id) == cols && out.rows == x.rows,
        "{entry} {label}: out is {}x{}, x is {}x{cols}",
        out.rows,
        plan.cols(out.id),
        x.rows
    );
    assert!(x.id != out.id, "{entry} {label}: cannot run in place");
    let params = SoftmaxParams { rows: x.rows as u32, cols: cols as u32, ld: plan.ld(x.id) as u32, scale, eps };
    plan.push(Op {
        label: label.to_string(),
        shader: &SOFTMAX,
        entry,
        params: params.words(),
        bindings: vec![(x, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid(groups),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
