//! Elementwise column maps (`shaders/elementwise.wgsl`): the model's final sigmoid, depth = exp(log-depth),
//! DeFiNe's depth from a sigmoid scaled to its range, and copying a channel range out of a wider tensor.

use super::ELEMENTWISE;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

/// Invocations per workgroup: one per vec4 of the output.
const GROUP_SIZE: usize = 64;

/// The function a [`map_columns`] op applies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Map {
    Identity,
    /// `1 / (1 + exp(-x))`, evaluated without overflow for any |x| (±inf give 1 and 0).
    Sigmoid,
    /// `exp(x)`.
    Exp,
    /// `sigmoid(x)·scale + offset` (DeFiNe's depth in its range).
    SigmoidAffine {
        scale: f32,
        offset: f32,
    },
    /// `log(sigmoid(x)·scale + offset)` (DeFiNe's log-depth).
    LogSigmoidAffine {
        scale: f32,
        offset: f32,
    },
}

impl Map {
    /// One of each variant ([`super::shader_codes`]).
    pub(super) const ALL: [Map; 5] = [
        Map::Identity,
        Map::Sigmoid,
        Map::Exp,
        Map::SigmoidAffine { scale: 1.0, offset: 0.0 },
        Map::LogSigmoidAffine { scale: 1.0, offset: 0.0 },
    ];

    /// The `MAP_*` constant of `shaders/elementwise.wgsl` and its value ([`super::ShaderCode`]).
    pub(super) fn constant(self) -> (&'static str, f64) {
        match self {
            Map::Identity => ("MAP_IDENTITY", 0.0),
            Map::Sigmoid => ("MAP_SIGMOID", 1.0),
            Map::Exp => ("MAP_EXP", 2.0),
            Map::SigmoidAffine { .. } => ("MAP_SIGMOID_AFFINE", 3.0),
            Map::LogSigmoidAffine { .. } => ("MAP_LOG_SIGMOID_AFFINE", 4.0),
        }
    }

    /// The code the shader reads and its two constants.
    fn code(self) -> (u32, f32, f32) {
        let (scale, offset) = match self {
            Map::SigmoidAffine { scale, offset } | Map::LogSigmoidAffine { scale, offset } => (scale, offset),
            _ => (1.0, 0.0),
        };
        (self.constant().1 as u32, scale, offset)
    }
}

params! {
    /// The uniform of `shaders/elementwise.wgsl`.
    ElementwiseParams {
        rows: u32,
        /// x's row stride in floats.
        x_ld: u32,
        /// First column of x read.
        col: u32,
        /// out's columns.
        cols: u32,
        /// out's row stride in vec4s.
        ld4: u32,
        /// The [`Map`]'s code and its constants.
        f: u32,
        scale: f32,
        offset: f32,
    }
}

/// A column map's operands: see [`map_columns`].
#[derive(Clone, Copy, Debug)]
pub struct MapColumnsArgs {
    pub x: View,
    /// First column of `x` read.
    pub col: usize,
    pub out: View,
    pub map: Map,
}

/// `out[r, j] = f(x[r, col + j])` for `j < cols(out)` and every row of the views; zero padding in `out`.
/// Identity copies bit for bit; the sigmoid is accurate to ~1e-7 absolute, exp and log to a few ulp relative
/// (the affine forms round as PyTorch's float32 `sigmoid(x) * scale + offset`). Records no multiply-adds
/// (elementwise work is not counted).
pub fn map_columns(plan: &mut PlanBuilder, label: &str, args: MapColumnsArgs) {
    let MapColumnsArgs { x, col, out, map: f } = args;
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
    let (code, scale, offset) = f.code();
    let params = ElementwiseParams {
        rows: x.rows as u32,
        x_ld: plan.ld(x.id) as u32,
        col: col as u32,
        cols: cols as u32,
        ld4: ld4 as u32,
        f: code,
        scale,
        offset,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &ELEMENTWISE,
        entry: "map_columns",
        params: params.words(),
        bindings: vec![(x, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid((x.rows * ld4).div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: 0, // elementwise: not multiply-add work worth counting
    });
}
