//! `nn.Linear` (and a 1×1 `nn.Conv2d` over NHWC rows, which is the same matrix product).

use super::{LayerNorm, Vars};
use crate::error::Result;
use crate::graph::Param;
use crate::graph::{Graph, Tensor};
use crate::kernels::matmul::{linear, LinearArgs, RowNorm};
use crate::kernels::Activation;

pub struct Linear {
    pub path: String,
    /// `[out, in]`.
    pub weight: Param,
    /// `[1, out]`.
    pub bias: Option<Param>,
    pub in_dim: usize,
    pub out_dim: usize,
}

impl Linear {
    /// `nn.Linear(in_dim, out_dim)`.
    pub fn new(vars: &Vars, in_dim: usize, out_dim: usize) -> Result<Linear> {
        Self::with_shape(vars, &[out_dim, in_dim], true)
    }

    /// `nn.Linear(in_dim, out_dim, bias=False)`.
    pub fn no_bias(vars: &Vars, in_dim: usize, out_dim: usize) -> Result<Linear> {
        Self::with_shape(vars, &[out_dim, in_dim], false)
    }

    /// `nn.Conv2d(in_dim, out_dim, kernel_size=1)`: weight `[out, in, 1, 1]`.
    pub fn conv1x1(vars: &Vars, in_dim: usize, out_dim: usize) -> Result<Linear> {
        Self::with_shape(vars, &[out_dim, in_dim, 1, 1], true)
    }

    fn with_shape(vars: &Vars, shape: &[usize], bias: bool) -> Result<Linear> {
        let (out_dim, in_dim) = (shape[0], shape[1]);
        Ok(Linear {
            path: vars.path().to_string(),
            weight: vars.matrix("weight", shape)?,
            bias: if bias { Some(vars.row("bias", out_dim)?) } else { None },
            in_dim,
            out_dim,
        })
    }

    /// `act(x · Wᵀ + b)` into a new tensor.
    pub fn forward(&self, g: &mut Graph, x: Tensor, act: Activation) -> Tensor {
        let out = g.transient(&self.path, x.rows(), self.out_dim);
        self.forward_into(g, x, out, act, false);
        out
    }

    /// `act(norm(x) · Wᵀ + b)` into a new tensor: a pre-norm and this layer, fused where the kernel can
    /// (`kernels::matmul::linear`).
    pub fn forward_normed(&self, g: &mut Graph, norm: &LayerNorm, x: Tensor, act: Activation) -> Tensor {
        let out = g.transient(&self.path, x.rows(), self.out_dim);
        let label = g.label(&self.path);
        let norm = RowNorm { gamma: g.param(&label, norm.gamma), beta: g.param(&label, norm.beta), eps: norm.eps };
        self.record(g, &label, x, out, act, false, Some(norm));
        out
    }

    /// `out = act(x · Wᵀ + b)`, or `out += ...` when `accumulate` (a residual connection).
    pub fn forward_into(&self, g: &mut Graph, x: Tensor, out: Tensor, act: Activation, accumulate: bool) {
        let label = g.label(&self.path);
        self.record(g, &label, x, out, act, accumulate, None);
    }

    #[allow(clippy::too_many_arguments)]
    fn record(
        &self,
        g: &mut Graph,
        label: &str,
        x: Tensor,
        out: Tensor,
        act: Activation,
        accumulate: bool,
        norm: Option<RowNorm>,
    ) {
        let weight = g.param(label, self.weight);
        let bias = self.bias.map(|b| g.param(label, b));
        linear(&mut g.b, label, LinearArgs { x: x.view, weight, bias, out: out.view, act, accumulate, norm });
    }
}

/// `x · yᵀ` of two tensors of the graph (`y` whole, as a linear layer's weight `[N, K]`) into a new
/// `[rows(x), N]` tensor named `path`: attention logits between computed queries and keys.
pub fn product_t(g: &mut Graph, path: &str, x: Tensor, y: Tensor) -> Tensor {
    let out = g.transient(path, x.rows(), y.rows());
    let label = g.label(path);
    let args = LinearArgs {
        x: x.view,
        weight: y.id(),
        bias: None,
        out: out.view,
        act: Activation::None,
        accumulate: false,
        norm: None,
    };
    linear(&mut g.b, &label, args);
    out
}
