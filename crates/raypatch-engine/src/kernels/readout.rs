//! A render's readout (`shaders/readout.wgsl`): the requested region of an output, packed densely for the host
//! to read with one copy, with a flag raised where a value is NaN or infinite.

use super::READOUT;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

params! {
    /// The uniform of `shaders/readout.wgsl`.
    ReadoutParams {
        views: u32,
        height: u32,
        width: u32,
        cols: u32,
        x_ld: u32,
    }
}

/// Invocations per workgroup: one per value read out.
const GROUP_SIZE: usize = 64;

/// Words of the host-written window (`Window` in the shader): first row, first column, rows, columns.
pub const WINDOW_WORDS: usize = 4;

/// A readout's operands: see [`read_region`].
#[derive(Clone, Copy, Debug)]
pub struct ReadoutArgs {
    /// The output, `[views * height * width, cols]`.
    pub x: View,
    pub views: usize,
    /// Each view's computed grid.
    pub height: usize,
    pub width: usize,
    /// At least `views * height * width * cols` floats, densely packed (its own row stride is not used).
    pub out: View,
    /// `[1, WINDOW_WORDS]`: the region inside the grid, as u32 words written by the host before each run.
    pub window: View,
    /// `[1, 1]`, zeroed by the host before each run: set to 1 when any value read out is not finite.
    pub flag: View,
}

/// `out[((v * h + r) * w + c) * cols + j] = x[(v * height + y + r) * width + x0 + c, j]` over the window
/// (y, x0, h, w) the host writes; dispatched for the whole grid, so any window inside it fits. Bit-exact.
pub fn read_region(plan: &mut PlanBuilder, label: &str, args: ReadoutArgs) {
    let ReadoutArgs { x, views, height, width, out, window, flag } = args;
    let cols = plan.cols(x.id);
    let values = views * height * width * cols;
    assert_eq!(x.rows, views * height * width, "read_region {label}: x is not {views} views of {height}x{width}");
    assert!(out.rows * plan.ld(out.id) >= values, "read_region {label}: out holds fewer than {values} floats");
    assert!(plan.cols(window.id) >= WINDOW_WORDS && plan.cols(flag.id) >= 1, "read_region {label}: window or flag");
    let params = ReadoutParams {
        views: views as u32,
        height: height as u32,
        width: width as u32,
        cols: cols as u32,
        x_ld: plan.ld(x.id) as u32,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &READOUT,
        entry: "read_region",
        params: params.words(),
        bindings: vec![(x, Access::Read), (out, Access::ReadWrite), (window, Access::Read), (flag, Access::ReadWrite)],
        textures: Vec::new(),
        workgroups: grid(values.div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
