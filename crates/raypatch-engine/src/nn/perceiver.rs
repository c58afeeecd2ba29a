//! The Perceiver layer of HuggingFace transformers 4.24 (`PerceiverLayer`, `PerceiverAttention`,
//! `PerceiverSelfAttention`, `PerceiverMLP`), as the official DeFiNe builds its encoder (`PerceiverModel`) and
//! decoders (`PerceiverBasicDecoder`) from it:
//!
//! ```text
//! a = output.dense(softmax(query(LN1(x)) · key(LN2(inputs))ᵀ / √d_head) · value(LN2(inputs)))  (+ x: query residual)
//! y = a + mlp.dense2(GELU(mlp.dense1(layernorm(a))))
//! ```
//!
//! Self-attention reads `inputs = x` with no second LayerNorm. Every LayerNorm is `nn.LayerNorm`'s default eps
//! 1e-5 (HF ignores the config's `layer_norm_eps` here). Query rows never interact, so a layer can run on any
//! slice of its queries: keys and values are projected once ([`PerceiverLayer::keys_values`]) and a scene's
//! decoder keeps them.

use super::{LayerNorm, Linear, Vars};
use crate::error::Result;
use crate::graph::{Graph, Tensor};
use crate::kernels::attention::{attention, AttentionArgs, MAX_DIM_HEAD};
use crate::kernels::mix::{mix_rows, MixArgs};
use crate::kernels::softmax::{softmax, Axis, SoftmaxArgs};
use crate::kernels::Activation;

/// The widths of one layer: queries `q_dim` wide; `kv_dim` wide inputs for cross-attention (`None`: self);
/// `heads` heads. As HF with `qk_channels = v_channels = None` and `cross_attention_shape_for_attention =
/// "kv"`: the attention is `kv_dim` wide for cross-attention and `q_dim` for self-attention, and the MLP
/// keeps `q_dim` (widening factor 1).
#[derive(Clone, Copy, Debug)]
pub struct PerceiverDims {
    pub q_dim: usize,
    pub kv_dim: Option<usize>,
    pub heads: usize,
    /// `use_query_residual`: the attention's output is added to its queries (the encoder's layers), or not
    /// (the decoders').
    pub query_residual: bool,
}

impl PerceiverDims {
    /// The attention width (`qk_channels`, equal to `v_channels`).
    pub fn inner(&self) -> usize {
        self.kv_dim.unwrap_or(self.q_dim)
    }
}

/// `PerceiverLayer`.
pub struct PerceiverLayer {
    pub path: String,
    pub dims: PerceiverDims,
    /// `attention.self.layernorm1` (queries) and `layernorm2` (cross-attention inputs).
    pub layernorm1: LayerNorm,
    pub layernorm2: Option<LayerNorm>,
    /// `attention.self.{query,key,value}`.
    pub query: Linear,
    pub key: Linear,
    pub value: Linear,
    /// `attention.output.dense`.
    pub output: Linear,
    /// `layernorm`, `mlp.dense1`, `mlp.dense2`.
    pub layernorm: LayerNorm,
    pub dense1: Linear,
    pub dense2: Linear,
}

/// Keys and values of a layer's inputs `[inputs, inner]` each.
#[derive(Clone, Copy, Debug)]
pub struct KeysValues {
    pub keys: Tensor,
    pub values: Tensor,
}

impl PerceiverLayer {
    pub fn new(vars: &Vars, dims: PerceiverDims) -> Result<PerceiverLayer> {
        let (q, inner) = (dims.q_dim, dims.inner());
        let kv = dims.kv_dim.unwrap_or(q);
        let at = vars.pp("attention.self");
        Ok(PerceiverLayer {
            path: vars.path().to_string(),
            dims,
            layernorm1: LayerNorm::new(&at.pp("layernorm1"), q)?,
            layernorm2: match dims.kv_dim {
                Some(kv_dim) => Some(LayerNorm::new(&at.pp("layernorm2"), kv_dim)?),
                None => None,
            },
            query: Linear::new(&at.pp("query"), q, inner)?,
            key: Linear::new(&at.pp("key"), kv, inner)?,
            value: Linear::new(&at.pp("value"), kv, inner)?,
            output: Linear::new(&vars.pp("attention.output.dense"), inner, q)?,
            layernorm: LayerNorm::new(&vars.pp("layernorm"), q)?,
            dense1: Linear::new(&vars.pp("mlp.dense1"), q, q)?,
            dense2: Linear::new(&vars.pp("mlp.dense2"), q, q)?,
        })
    }

    /// The widest row of a query inside the layer besides the scores (sizes query chunks).
    pub fn widest(&self) -> usize {
        self.dims.inner().max(self.dims.q_dim)
    }

    /// Whether the attention materialises its `[queries, inputs]` scores (heads wider than the fused
    /// kernel's [`MAX_DIM_HEAD`]: DeFiNe's single-head cross-attentions), so query chunks must hold them.
    pub fn materialises_scores(&self) -> bool {
        self.dims.inner() / self.dims.heads > MAX_DIM_HEAD
    }

    /// The cross-attention's keys and values of `inputs` `[n, kv_dim]`: key/value(layernorm2(inputs)), into
    /// `out` (tensors `[n, inner]`).
    pub fn keys_values(&self, g: &mut Graph, inputs: Tensor, out: KeysValues) {
        let normed = match &self.layernorm2 {
            Some(norm) => norm.forward(g, inputs),
            None => inputs,
        };
        self.key.forward_into(g, normed, out.keys, Activation::None, false);
        self.value.forward_into(g, normed, out.values, Activation::None, false);
    }

    /// The layer on the queries `x` `[rows, q_dim]`, attending to `kv` (cross-attention) or to `x` itself
    /// (`None`: self-attention). With the query residual `x` is updated in place and returned; without it
    /// the result is a new tensor.
    pub fn forward(&self, g: &mut Graph, x: Tensor, kv: Option<KeysValues>) -> Tensor {
        let normed = self.layernorm1.forward(g, x);
        let q = self.query.forward(g, normed, Activation::None);
        let kv = kv.unwrap_or_else(|| KeysValues {
            keys: self.key.forward(g, normed, Activation::None),
            values: self.value.forward(g, normed, Activation::None),
        });
        let context = self.attend(g, q, kv);
        let out = if self.dims.query_residual {
            self.output.forward_into(g, context, x, Activation::None, true);
            x
        } else {
            self.output.forward(g, context, Activation::None)
        };
        let normed = self.layernorm.forward(g, out);
        let hidden = self.dense1.forward(g, normed, Activation::Gelu);
        self.dense2.forward_into(g, hidden, out, Activation::None, true);
        out
    }

    /// softmax(q·kᵀ / √d_head)·v per head: the fused online-softmax kernel, or for a single head wider than
    /// it takes, the scores materialised (a matrix product, a row softmax, the weighted sum of the values).
    fn attend(&self, g: &mut Graph, q: Tensor, kv: KeysValues) -> Tensor {
        let (heads, inner) = (self.dims.heads, self.dims.inner());
        let dim_head = inner / heads;
        // HF divides the scores by √d_head; the kernels multiply by its reciprocal (equal within an ulp).
        let scale = 1.0 / (dim_head as f32).sqrt();
        let path = format!("{}.attention.self", self.path);
        let out = g.transient(&format!("{path}.context"), q.rows(), inner);
        let label = g.label(&format!("{path}.context"));
        if !self.materialises_scores() {
            let args = AttentionArgs {
                q: q.view,
                q_col: 0,
                k: kv.keys.view,
                k_col: 0,
                v: kv.values.view,
                v_col: 0,
                out: out.view,
                heads,
                dim_head,
                scale,
            };
            attention(&mut g.b, &label, args);
            return out;
        }
        assert_eq!(heads, 1, "{path}: heads wider than {MAX_DIM_HEAD} are taken one head at a time");
        let scores = super::product_t(g, &format!("{path}.scores"), q, kv.keys);
        let weights = g.transient(&format!("{path}.weights"), q.rows(), kv.keys.rows());
        let softmax_label = g.label(&format!("{path}.weights"));
        let args = SoftmaxArgs { x: scores.view, out: weights.view, axis: Axis::Rows, scale, eps: 0.0 };
        softmax(&mut g.b, &softmax_label, args);
        mix_rows(&mut g.b, &label, MixArgs { w: weights.view, x: kv.values.id(), out: out.view });
        out
    }
}
