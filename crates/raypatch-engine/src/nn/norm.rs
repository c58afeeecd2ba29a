//! `nn.LayerNorm` (eps 1e-5, affine).

use super::Vars;
use crate::error::Result;
use crate::graph::Param;
use crate::graph::{Graph, Tensor};
use crate::kernels::norm::{layernorm, LayerNormArgs};

/// LayerNorm eps of every official transformer (PyTorch's default).
pub const LAYER_NORM_EPS: f32 = 1e-5;

pub struct LayerNorm {
    pub path: String,
    /// `[1, dim]` scale and shift.
    pub gamma: Param,
    pub beta: Param,
    pub eps: f32,
}

impl LayerNorm {
    pub fn new(vars: &Vars, dim: usize) -> Result<LayerNorm> {
        Ok(LayerNorm {
            path: vars.path().to_string(),
            gamma: vars.row("weight", dim)?,
            beta: vars.row("bias", dim)?,
            eps: LAYER_NORM_EPS,
        })
    }

    /// The normalised rows of `x`, in a new tensor.
    pub fn forward(&self, g: &mut Graph, x: Tensor) -> Tensor {
        let out = g.transient(&self.path, x.rows(), x.cols);
        let label = g.label(&self.path);
        let (gamma, beta) = (g.param(&label, self.gamma), g.param(&label, self.beta));
        layernorm(&mut g.b, &label, LayerNormArgs { x: x.view, gamma, beta, out: out.view, eps: self.eps });
        out
    }
}
