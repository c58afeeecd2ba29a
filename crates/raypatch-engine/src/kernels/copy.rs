//! Copies into a column range (`shaders/copy.wgsl`), with a row broadcast: how DeFiNe assembles its tokens
//! and queries, `cat(features..., ray, camera position, encodings)`, from parts computed separately.

use super::COPY;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

params! {
    /// The uniform of `shaders/copy.wgsl`.
    CopyParams {
        rows: u32,
        cols: u32,
        /// Floats per row of x.
        x_ld: u32,
        /// Floats per row of out.
        out_ld: u32,
        col: u32,
        repeat: u32,
        first_row: u32,
    }
}

/// Invocations per workgroup: one per copied element.
const GROUP_SIZE: usize = 64;

/// A copy's operands: see [`copy_columns`].
#[derive(Clone, Copy, Debug)]
pub struct CopyArgs {
    /// `[R, cols]` view.
    pub x: View,
    /// Rows of `out` per row of `x` (1: row for row).
    pub repeat: usize,
    /// Index of `out`'s first row in the broadcast.
    pub first_row: usize,
    pub out: View,
    /// First column of `out` written.
    pub col: usize,
}

/// `out[r, col + j] = x[(first_row + r) / repeat, j]` for every row of `out` and `j < cols(x)`; `out`'s other
/// columns (its padding included) are left as they are. Bit-exact. Records no multiply-adds (a copy).
pub fn copy_columns(plan: &mut PlanBuilder, label: &str, args: CopyArgs) {
    let CopyArgs { x, repeat, first_row, out, col } = args;
    let cols = plan.cols(x.id);
    assert!(repeat > 0 && cols > 0, "copy_columns {label}: repeat and columns must be positive");
    assert!(
        col + cols <= plan.cols(out.id),
        "copy_columns {label}: columns {col}..{} past the {} of out",
        col + cols,
        plan.cols(out.id)
    );
    assert!(
        out.rows == 0 || (first_row + out.rows - 1) / repeat < x.rows,
        "copy_columns {label}: rows {first_row}..{} with repeat {repeat} need more than {} rows of x",
        first_row + out.rows,
        x.rows
    );
    assert!(x.id != out.id, "copy_columns {label}: x and out must be different tensors");
    let params = CopyParams {
        rows: out.rows as u32,
        cols: cols as u32,
        x_ld: plan.ld(x.id) as u32,
        out_ld: plan.ld(out.id) as u32,
        col: col as u32,
        repeat: repeat as u32,
        first_row: first_row as u32,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &COPY,
        entry: "copy_columns",
        params: params.words(),
        bindings: vec![(x, Access::Read), (out, Access::ReadWrite)],
        textures: Vec::new(),
        workgroups: grid((out.rows * cols).div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
