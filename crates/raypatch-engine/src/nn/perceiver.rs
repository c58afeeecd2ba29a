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
//!
//! DeFiNe's cross-attentions have one head 1146 or 512 wide, beyond the fused attention kernel: their scores
//! are materialised per query chunk (a matrix product and a row softmax) and the weighted sum of the values is
//! a matrix product too, with the values kept transposed and without their bias (see [`Values`]).

use super::{LayerNorm, Linear, Vars};
use crate::error::Result;
use crate::graph::Param;
use crate::graph::{Graph, Tensor};
use crate::kernels::attention::{attention, AttentionArgs, MAX_DIM_HEAD};
use crate::kernels::matmul::{linear, LinearArgs};
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
    pub value: Values,
    /// `attention.output.dense`.
    pub output: Linear,
    /// `layernorm`, `mlp.dense1`, `mlp.dense2`.
    pub layernorm: LayerNorm,
    pub dense1: Linear,
    pub dense2: Linear,
}

/// How a layer projects its values.
pub enum Values {
    /// `value` as an `nn.Linear`: values `[inputs, inner]`, as the fused attention kernel reads them.
    Rows(Linear),
    /// `value`'s weight `[inner, kv_dim]` read as data (f32) and its bias: values kept transposed and without
    /// the bias, `[inner, inputs]`, so that softmax·V is a matrix product whose bias is `value.bias` (each row
    /// of the softmax sums to 1, so the bias passes through it unchanged).
    Transposed { path: String, weight: Param, bias: Param },
}

/// Keys `[inputs, inner]` and values (shaped as [`PerceiverLayer::values_shape`] says) of a layer's inputs.
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
        let value = at.pp("value");
        let value = if inner / dims.heads > MAX_DIM_HEAD {
            let path = value.path().to_string();
            Values::Transposed { path, weight: value.dense("weight", inner, kv)?, bias: value.row("bias", inner)? }
        } else {
            Values::Rows(Linear::new(&value, kv, inner)?)
        };
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
            value,
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

    /// The shape `[rows, cols]` of the values of `inputs` inputs: `[inputs, inner]`, or transposed.
    pub fn values_shape(&self, inputs: usize) -> (usize, usize) {
        match self.value {
            Values::Rows(_) => (inputs, self.dims.inner()),
            Values::Transposed { .. } => (self.dims.inner(), inputs),
        }
    }

    /// The cross-attention's keys and values of `inputs` `[n, kv_dim]`: key/value(layernorm2(inputs)), into
    /// `out` (keys `[n, inner]`, values as [`values_shape`](Self::values_shape)).
    pub fn keys_values(&self, g: &mut Graph, inputs: Tensor, out: KeysValues) {
        let normed = match &self.layernorm2 {
            Some(norm) => norm.forward(g, inputs),
            None => inputs,
        };
        self.key.forward_into(g, normed, out.keys, Activation::None, false);
        match &self.value {
            Values::Rows(value) => value.forward_into(g, normed, out.values, Activation::None, false),
            // Vᵀ without the bias: value.weight · normedᵀ.
            Values::Transposed { path, weight, .. } => {
                let label = g.label(path);
                let weight = g.param(&label, *weight);
                let x = g.b.all(weight);
                let args = LinearArgs {
                    x,
                    weight: normed.id(),
                    bias: None,
                    out: out.values.view,
                    act: Activation::None,
                    accumulate: false,
                    norm: None,
                };
                linear(&mut g.b, &label, args);
            }
        }
    }

    /// The layer on the queries `x` `[rows, q_dim]`, attending to `kv` (cross-attention) or to `x` itself
    /// (`None`: self-attention). With the query residual `x` is updated in place and returned; without it
    /// the result is a new tensor.
    pub fn forward(&self, g: &mut Graph, x: Tensor, kv: Option<KeysValues>) -> Tensor {
        let normed = self.layernorm1.forward(g, x);
        let q = self.query.forward(g, normed, Activation::None);
        let kv = kv.unwrap_or_else(|| {
            let Values::Rows(value) = &self.value else {
                panic!("{}: self-attention with heads wider than {MAX_DIM_HEAD}", self.path)
            };
            KeysValues {
                keys: self.key.forward(g, normed, Activation::None),
                values: value.forward(g, normed, Activation::None),
            }
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
    /// it takes, the scores materialised (a matrix product, a row softmax, the weighted sum of the transposed
    /// values as a matrix product plus the value bias).
    fn attend(&self, g: &mut Graph, q: Tensor, kv: KeysValues) -> Tensor {
        let (heads, inner) = (self.dims.heads, self.dims.inner());
        let dim_head = inner / heads;
        // HF divides the scores by √d_head; the kernels multiply by its reciprocal (equal within an ulp).
        let scale = 1.0 / (dim_head as f32).sqrt();
        let path = format!("{}.attention.self", self.path);
        let out = g.transient(&format!("{path}.context"), q.rows(), inner);
        let label = g.label(&format!("{path}.context"));
        let Values::Transposed { bias, .. } = &self.value else {
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
        };
        assert_eq!(heads, 1, "{path}: heads wider than {MAX_DIM_HEAD} are taken one head at a time");
        let scores = super::product_t(g, &format!("{path}.scores"), q, kv.keys);
        let weights = g.transient(&format!("{path}.weights"), q.rows(), kv.keys.rows());
        let softmax_label = g.label(&format!("{path}.weights"));
        let args = SoftmaxArgs { x: scores.view, out: weights.view, axis: Axis::Rows, scale, eps: 0.0 };
        softmax(&mut g.b, &softmax_label, args);
        let bias = g.param(&label, *bias);
        let args = LinearArgs {
            x: weights.view,
            weight: kv.values.id(),
            bias: Some(bias),
            out: out.view,
            act: Activation::None,
            accumulate: false,
            norm: None,
        };
        linear(&mut g.b, &label, args);
        out
    }
}
