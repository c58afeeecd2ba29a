//! Elementwise column maps (`shaders/elementwise.wgsl`): the model's final sigmoid, and copying a channel
//! range out of a wider tensor.

use super::ELEMENTWISE;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

/// Invocations per workgroup: one per vec4 of the output.
const GROUP_SIZE: usize = 64;

/// The function a [`map_columns`] op applies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Map {
    Identity,
    /// `1 / (1 + exp(-x))`, evaluated without overflow for any |x| (±inf give 1 and 0).
    Sigmoid,
}

impl Map {
    /// The code the shader reads.
    fn code(self) -> u32 {
        match self {
            Map::Identity => 0,
            Map::Sigmoid => 1,
        }
    }
}

/// `out[r, j] = f(x[r, col + j])` for `j < cols(out)` and every row of the views; zero padding in `out`.
/// Identity copies bit for bit; the sigmoid is accurate to ~1e-7 absolute.
pub fn map_columns(plan: &mut PlanBuilder, label: &str, x: View, col: usize, out: View, f: Map) {
    let cols = plan.cols(out.id);
    assert!(cols > 0, "map_columns {label}: out has no columns");
    assert!(
        col + cols <= plan.cols(x.id),
        "map_columns {label}: columns {col}..{} past the {} of x",
        col + cols,
        plan.cols(x.id)
    );
    assert_eq!(out.rows, x.rows, "map_columns {label}: out has {} rows, x has {}", out.rows, x.rows);
    assert!(x.id != out.id, "map_columns {label}: cannot run in place");
    let ld4 = plan.ld(out.id) / 4;
    let params = vec![x.rows as u32, plan.ld(x.id) as u32, col as u32, cols as u32, ld4 as u32, f.code()];
    plan.push(Op {
        label: label.to_string(),
        shader: &ELEMENTWISE,
        entry: "map_columns",
        params,
        bindings: vec![(x, Access::Read), (out, Access::Write)],
        workgroups: grid((x.rows * ld4).div_ceil(GROUP_SIZE)),
    });
}
