//! The official `SlotAttention` (RayPatchQuerying `src/layers.py`, after Locatello et al.): learned initial
//! slots attend to the LayerNormed inputs, with the softmax over slots (+1e-8) renormalised over inputs; the
//! updates go through a GRU cell and a residual MLP, `iters` times.

use raypatch_model::SlotAttentionConfig;

use super::linear::product_t;
use super::{GruCell, LayerNorm, Linear, Vars};
use crate::error::Result;
use crate::graph::Param;
use crate::graph::{Graph, Tensor};
use crate::kernels::mix::{mix_rows, MixArgs};
use crate::kernels::softmax::{normalize_rows, softmax, Axis, SoftmaxArgs};
use crate::kernels::Activation;

/// Added to every attention weight before the renormalisation over inputs (the official `eps`).
pub const SLOT_ATTENTION_EPS: f32 = 1e-8;

pub struct SlotAttention {
    pub path: String,
    /// `initial_slots` `[num_slots, slot_dim]`.
    pub initial_slots: Param,
    pub to_q: Linear,
    pub to_k: Linear,
    pub to_v: Linear,
    pub gru: GruCell,
    /// `mlp.0` (ReLU) and `mlp.2`.
    pub mlp_0: Linear,
    pub mlp_2: Linear,
    pub norm_input: LayerNorm,
    pub norm_slots: LayerNorm,
    pub norm_pre_mlp: LayerNorm,
    pub num_slots: usize,
    pub slot_dim: usize,
    pub iters: usize,
}

impl SlotAttention {
    /// Slot attention over inputs `input_dim` wide.
    pub fn new(vars: &Vars, c: &SlotAttentionConfig, input_dim: usize) -> Result<SlotAttention> {
        let d = c.slot_dim;
        Ok(SlotAttention {
            path: vars.path().to_string(),
            initial_slots: vars.dense("initial_slots", c.num_slots, d)?,
            to_q: Linear::no_bias(&vars.pp("to_q"), d, d)?,
            to_k: Linear::no_bias(&vars.pp("to_k"), input_dim, d)?,
            to_v: Linear::no_bias(&vars.pp("to_v"), input_dim, d)?,
            gru: GruCell::new(&vars.pp("gru"), d, d)?,
            mlp_0: Linear::new(&vars.pp("mlp.0"), d, c.hidden)?,
            mlp_2: Linear::new(&vars.pp("mlp.2"), c.hidden, d)?,
            norm_input: LayerNorm::new(&vars.pp("norm_input"), input_dim)?,
            norm_slots: LayerNorm::new(&vars.pp("norm_slots"), d)?,
            norm_pre_mlp: LayerNorm::new(&vars.pp("norm_pre_mlp"), d)?,
            num_slots: c.num_slots,
            slot_dim: d,
            iters: c.iters,
        })
    }

    /// The slots `[num_slots, slot_dim]` of one scene's inputs `[tokens, input_dim]`, written into `out`.
    pub fn forward_into(&self, g: &mut Graph, inputs: Tensor, out: Tensor) {
        let x = self.norm_input.forward(g, inputs);
        let k = self.to_k.forward(g, x, Activation::None);
        let v = self.to_v.forward(g, x, Activation::None);
        let initial = g.param(&g.label(&format!("{}.initial_slots", self.path)), self.initial_slots);
        let mut slots = Tensor { view: g.b.all(initial), cols: self.slot_dim, image: None };
        let scale = (self.slot_dim as f32).powf(-0.5);
        let (n, d) = (self.num_slots, self.slot_dim);
        for iter in 0..self.iters {
            let at = |name: &str| format!("{}.iter{iter}.{name}", self.path);
            let normed = self.norm_slots.forward(g, slots);
            let q = self.to_q.forward(g, normed, Activation::None);
            // dots [slots, inputs]; attn = softmax over slots + eps, renormalised over inputs.
            let dots = product_t(g, &at("dots"), q, k);
            let attn = g.transient(&at("attn"), n, inputs.rows());
            let args =
                SoftmaxArgs { x: dots.view, out: attn.view, axis: Axis::Columns, scale, eps: SLOT_ATTENTION_EPS };
            let label = g.label(&at("attn"));
            softmax(&mut g.b, &label, args);
            let attn_norm = g.transient(&at("attn_norm"), n, inputs.rows());
            let label = g.label(&at("attn_norm"));
            normalize_rows(&mut g.b, &label, attn.view, attn_norm.view);
            let updates = g.transient(&at("updates"), n, d);
            let label = g.label(&at("updates"));
            mix_rows(&mut g.b, &label, MixArgs { w: attn_norm.view, x: v.id(), out: updates.view });
            // slots = GRU(updates, slots); slots += mlp(norm_pre_mlp(slots)).
            let next = if iter + 1 == self.iters { out } else { g.transient(&at("slots"), n, d) };
            self.gru.forward_into(g, updates, slots, next);
            let normed = self.norm_pre_mlp.forward(g, next);
            let hidden = self.mlp_0.forward(g, normed, Activation::Relu);
            self.mlp_2.forward_into(g, hidden, next, Activation::None, true);
            slots = next;
        }
    }
}
