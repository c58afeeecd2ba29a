//! The official `Transformer` (srt `layers.py`): pre-norm layers of `PreNorm(Attention)` then
//! `PreNorm(FeedForward)`, each added to its input. Self-attention projects q, k, v from the tokens
//! (`to_qkv`); cross-attention projects q from the queries (`to_q`) and k, v from the latent (`to_kv`), which
//! a scene computes once ([`Transformer::keys_values`]) and every render reuses.

use super::{LayerNorm, Linear, Vars};
use crate::error::Result;
use crate::graph::{Graph, Tensor};
use crate::kernels::attention::{attention, AttentionArgs};
use crate::kernels::Activation;

/// Widths of a transformer: `dim` tokens, `heads` × `dim_head` attention, `mlp_dim` feed-forward, and the
/// key/value width for cross-attention (`None`: self-attention).
#[derive(Clone, Copy, Debug)]
pub struct TransformerDims {
    pub dim: usize,
    pub depth: usize,
    pub heads: usize,
    pub dim_head: usize,
    pub mlp_dim: usize,
    pub kv_dim: Option<usize>,
}

/// `Attention`: the projections, softmax(q·kᵀ·scale)·v per head, and `to_out`.
pub struct Attention {
    pub path: String,
    pub heads: usize,
    pub dim_head: usize,
    pub projections: Projections,
    /// `to_out.1`.
    pub to_out: Linear,
}

pub enum Projections {
    /// `to_qkv`: `[3·inner, dim]`.
    SelfAttention { to_qkv: Linear },
    /// `to_q`: `[inner, dim]`; `to_kv`: `[2·inner, kv_dim]`.
    Cross { to_q: Linear, to_kv: Linear },
}

/// `FeedForward`: Linear → GELU → Linear (`net.0`, `net.3`).
pub struct FeedForward {
    pub net_0: Linear,
    pub net_3: Linear,
}

pub struct TransformerLayer {
    /// `{l}.0.norm`, `{l}.0.fn`.
    pub attn_norm: LayerNorm,
    pub attn: Attention,
    /// `{l}.1.norm`, `{l}.1.fn`.
    pub ff_norm: LayerNorm,
    pub ff: FeedForward,
}

pub struct Transformer {
    pub layers: Vec<TransformerLayer>,
}

impl Transformer {
    /// The transformer at `vars` (its `layers.{l}` below it).
    pub fn new(vars: &Vars, d: TransformerDims) -> Result<Transformer> {
        let inner = d.heads * d.dim_head;
        let layers = (0..d.depth)
            .map(|l| {
                let layer = vars.pp("layers").pp(l);
                let (attn, ff) = (layer.pp(0), layer.pp(1));
                let at = attn.pp("fn");
                let projections = match d.kv_dim {
                    None => Projections::SelfAttention { to_qkv: Linear::no_bias(&at.pp("to_qkv"), d.dim, 3 * inner)? },
                    Some(kv_dim) => Projections::Cross {
                        to_q: Linear::no_bias(&at.pp("to_q"), d.dim, inner)?,
                        to_kv: Linear::no_bias(&at.pp("to_kv"), kv_dim, 2 * inner)?,
                    },
                };
                Ok(TransformerLayer {
                    attn_norm: LayerNorm::new(&attn.pp("norm"), d.dim)?,
                    attn: Attention {
                        path: at.path().to_string(),
                        heads: d.heads,
                        dim_head: d.dim_head,
                        projections,
                        to_out: Linear::new(&at.pp("to_out.1"), inner, d.dim)?,
                    },
                    ff_norm: LayerNorm::new(&ff.pp("norm"), d.dim)?,
                    ff: FeedForward {
                        net_0: Linear::new(&ff.pp("fn.net.0"), d.dim, d.mlp_dim)?,
                        net_3: Linear::new(&ff.pp("fn.net.3"), d.mlp_dim, d.dim)?,
                    },
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Transformer { layers })
    }

    /// Self-attention layers on the tokens `x`, in place.
    pub fn forward(&self, g: &mut Graph, x: Tensor) {
        for layer in &self.layers {
            let heads = layer.attn.attend_self(g, &layer.attn_norm, x);
            layer.attn.to_out.forward_into(g, heads, x, Activation::None, true);
            layer.ff.forward_residual(g, &layer.ff_norm, x);
        }
    }

    /// Cross-attention layers from the queries `x`, in place, to each layer's keys and values
    /// (from [`keys_values`](Self::keys_values)).
    pub fn forward_cross(&self, g: &mut Graph, x: Tensor, keys_values: &[Tensor]) {
        for (layer, &kv) in self.layers.iter().zip(keys_values) {
            let heads = layer.attn.attend_cross(g, &layer.attn_norm, x, kv);
            layer.attn.to_out.forward_into(g, heads, x, Activation::None, true);
            layer.ff.forward_residual(g, &layer.ff_norm, x);
        }
    }

    /// Each cross-attention layer's `to_kv(z)` `[tokens, 2·inner]` (keys, then values) into `outputs`.
    pub fn keys_values(&self, g: &mut Graph, z: Tensor, outputs: &[Tensor]) {
        for (layer, &out) in self.layers.iter().zip(outputs) {
            if let Projections::Cross { to_kv, .. } = &layer.attn.projections {
                to_kv.forward_into(g, z, out, Activation::None, false);
            }
        }
    }

    /// Width of each layer's keys and values (`2·inner`).
    pub fn kv_width(&self) -> usize {
        self.layers.first().map_or(0, |l| 2 * l.attn.heads * l.attn.dim_head)
    }
}

impl Attention {
    fn inner(&self) -> usize {
        self.heads * self.dim_head
    }

    fn scale(&self) -> f32 {
        (self.dim_head as f32).powf(-0.5)
    }

    /// Self-attention heads `[rows, inner]` from the tokens, normed by `norm`.
    fn attend_self(&self, g: &mut Graph, norm: &LayerNorm, x: Tensor) -> Tensor {
        let Projections::SelfAttention { to_qkv } = &self.projections else {
            panic!("{}: a cross-attention layer used as self-attention", self.path)
        };
        let qkv = to_qkv.forward_normed(g, norm, x, Activation::None);
        self.attend(g, x.rows(), (qkv, 0), (qkv, self.inner()), (qkv, 2 * self.inner()))
    }

    /// Cross-attention heads `[rows, inner]` from the queries, normed by `norm`, and the layer's keys and
    /// values.
    fn attend_cross(&self, g: &mut Graph, norm: &LayerNorm, x: Tensor, kv: Tensor) -> Tensor {
        let Projections::Cross { to_q, .. } = &self.projections else {
            panic!("{}: a self-attention layer used as cross-attention", self.path)
        };
        let q = to_q.forward_normed(g, norm, x, Activation::None);
        self.attend(g, x.rows(), (q, 0), (kv, 0), (kv, self.inner()))
    }

    /// softmax(q·kᵀ·scale)·v per head; each of q, k, v is (tensor, first column).
    fn attend(&self, g: &mut Graph, rows: usize, q: (Tensor, usize), k: (Tensor, usize), v: (Tensor, usize)) -> Tensor {
        let out = g.transient(&format!("{}.attend", self.path), rows, self.inner());
        let label = g.label(&format!("{}.attend", self.path));
        let args = AttentionArgs {
            q: q.0.view,
            q_col: q.1,
            k: k.0.view,
            k_col: k.1,
            v: v.0.view,
            v_col: v.1,
            out: out.view,
            heads: self.heads,
            dim_head: self.dim_head,
            scale: self.scale(),
        };
        attention(&mut g.b, &label, args);
        out
    }
}

impl FeedForward {
    /// x += FF(norm(x)).
    pub fn forward_residual(&self, g: &mut Graph, norm: &LayerNorm, x: Tensor) {
        let hidden = self.net_0.forward_normed(g, norm, x, Activation::Gelu);
        self.net_3.forward_into(g, hidden, x, Activation::None, true);
    }
}
