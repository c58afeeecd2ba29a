//! `nn.GRUCell`: the two gate projections `x·W_ihᵀ + b_ih` and `h·W_hhᵀ + b_hh` (`[3·dim, ...]`, gates r, z, n
//! in PyTorch's order), then the gates (`kernels::gru`).

use super::{Linear, Vars};
use crate::error::Result;
use crate::graph::{Graph, Tensor};
use crate::kernels::gru::{gru_cell, GruArgs};
use crate::kernels::Activation;

pub struct GruCell {
    pub path: String,
    /// `weight_ih` `[3·hidden, input]` with `bias_ih`.
    pub input_gates: Linear,
    /// `weight_hh` `[3·hidden, hidden]` with `bias_hh`.
    pub hidden_gates: Linear,
    pub hidden: usize,
}

impl GruCell {
    /// `nn.GRUCell(input, hidden)` at `vars`.
    pub fn new(vars: &Vars, input: usize, hidden: usize) -> Result<GruCell> {
        let gates = |kind: &str, width: usize| -> Result<Linear> {
            Ok(Linear {
                path: format!("{}.{kind}", vars.path()),
                weight: vars.matrix(&format!("weight_{kind}"), &[3 * hidden, width])?,
                bias: Some(vars.row(&format!("bias_{kind}"), 3 * hidden)?),
                in_dim: width,
                out_dim: 3 * hidden,
            })
        };
        Ok(GruCell {
            path: vars.path().to_string(),
            input_gates: gates("ih", input)?,
            hidden_gates: gates("hh", hidden)?,
            hidden,
        })
    }

    /// The next hidden state from the input `x` and the state `h`, into `out` (another tensor than `h`).
    pub fn forward_into(&self, g: &mut Graph, x: Tensor, h: Tensor, out: Tensor) {
        let gi = self.input_gates.forward(g, x, Activation::None);
        let gh = self.hidden_gates.forward(g, h, Activation::None);
        let label = g.label(&self.path);
        gru_cell(&mut g.b, &label, GruArgs { gi: gi.view, gh: gh.view, h: h.view, out: out.view });
    }
}
