//! OSRT in float64 (`models/osrt.rs`, `nn/slot_attention.rs`, `nn/gru.rs`): slot attention on the SRT
//! encoder's tokens, and the `SlotMixerDecoder` (allocation transformer, mixing block, render MLP).

use super::srt::RayPredictor;
use super::{leaky_relu, Dense, Norm, QueryRows, Reader, ReferenceScene, OUT_MLP_SLOPE};
use crate::concat::concat_columns;
use crate::gru::gru_cell;
use crate::matmul::linear;
use crate::mix::mix_rows;
use crate::softmax::{normalize_rows, softmax};
use raypatch_engine::kernels::softmax::Axis;
use raypatch_engine::kernels::Activation;
use raypatch_engine::models::osrt::{MixingBlock as EngineMixingBlock, Osrt as EngineOsrt};
use raypatch_engine::nn::SlotAttention as EngineSlotAttention;

/// Added to every slot-attention weight before the renormalisation over inputs (the official `eps`), as
/// float64 torch has it.
const SLOT_ATTENTION_EPS: f64 = 1e-8;

/// `SlotAttention` with learned initial slots.
struct SlotAttention {
    /// `[num_slots, slot_dim]`.
    initial_slots: Vec<f64>,
    to_q: Dense,
    to_k: Dense,
    to_v: Dense,
    /// The GRU cell's gate projections `weight_ih`/`bias_ih` and `weight_hh`/`bias_hh` (gates r, z, n).
    gru_input: Dense,
    gru_hidden: Dense,
    /// `mlp.0` (ReLU), `mlp.2`.
    mlp: (Dense, Dense),
    norm_input: Norm,
    norm_slots: Norm,
    norm_pre_mlp: Norm,
    iters: usize,
}

/// `MixingBlock`: `w = softmax_slots(to_q(x)·to_k(slots)ᵀ·att_dim^-0.5)`, `s = Σ w·slots`, with the optional
/// LayerNorms `norm1` (on x) and `norm2` (on s).
struct MixingBlock {
    to_q: Dense,
    to_k: Dense,
    norms: Option<(Norm, Norm)>,
}

/// `RenderMLP`: four Linear + LeakyReLU(0.01) layers, then the output layer, followed by a LeakyReLU when it
/// emits Ray-Patch features (out ≠ 3) rather than rgb.
struct RenderMlp {
    layers: Vec<Dense>,
    final_leaky_relu: bool,
}

/// `SlotMixerDecoder`.
pub(super) struct SlotMixer {
    allocation_transformer: RayPredictor,
    mixing_block: MixingBlock,
    render_mlp: RenderMlp,
}

/// What OSRT adds to the SRT encoder, and its decoder.
pub(super) struct Osrt {
    slot_attention: SlotAttention,
    pub(super) decoder: SlotMixer,
}

impl Osrt {
    pub(super) fn read(r: &Reader, m: &EngineOsrt) -> Osrt {
        let d = &m.decoder;
        Osrt {
            slot_attention: SlotAttention::read(r, &m.encoder.slot_attention),
            decoder: SlotMixer {
                allocation_transformer: RayPredictor::read(r, &d.allocation_transformer),
                mixing_block: MixingBlock::read(r, &d.mixing_block),
                render_mlp: RenderMlp {
                    layers: d.render_mlp.layers.iter().map(|l| r.dense(l)).collect(),
                    final_leaky_relu: d.render_mlp.final_activation != Activation::None,
                },
            },
        }
    }

    /// The encoded scene of the SRT encoder's tokens (the set latent): the slots, the allocation
    /// transformer's keys and values and the mixing block's keys of them.
    pub(super) fn scene(&self, set_latent: Vec<f64>) -> ReferenceScene {
        let slots = self.slot_attention.forward(&set_latent);
        let d = &self.decoder;
        ReferenceScene {
            keys_values: d.allocation_transformer.keys_values(&slots),
            mixing_keys: Some(d.mixing_block.to_k.forward(&slots)),
            tokens: slots.len() / self.slot_attention.slot_dim(),
            latent: slots,
            set_latent: Some(set_latent),
        }
    }
}

impl SlotAttention {
    fn read(r: &Reader, s: &EngineSlotAttention) -> SlotAttention {
        SlotAttention {
            initial_slots: r.get(s.initial_slots),
            to_q: r.dense(&s.to_q),
            to_k: r.dense(&s.to_k),
            to_v: r.dense(&s.to_v),
            gru_input: r.dense(&s.gru.input_gates),
            gru_hidden: r.dense(&s.gru.hidden_gates),
            mlp: (r.dense(&s.mlp_0), r.dense(&s.mlp_2)),
            norm_input: r.norm(&s.norm_input),
            norm_slots: r.norm(&s.norm_slots),
            norm_pre_mlp: r.norm(&s.norm_pre_mlp),
            iters: s.iters,
        }
    }

    fn slot_dim(&self) -> usize {
        self.to_q.n
    }

    /// The slots `[num_slots, slot_dim]` of the inputs `[tokens, input_dim]`: x = LN(inputs), k = to_k(x),
    /// v = to_v(x); per iteration q = to_q(LN(slots)), attn = softmax over slots of q·kᵀ·slot_dim^-0.5 + eps,
    /// renormalised over the inputs, slots = GRUCell(attn·v, slots), slots += mlp(LN(slots)).
    fn forward(&self, inputs: &[f64]) -> Vec<f64> {
        let x = self.norm_input.apply(inputs);
        let (k, v) = (self.to_k.forward(&x), self.to_v.forward(&x));
        let d = self.slot_dim();
        let (slots_n, tokens) = (self.initial_slots.len() / d, k.len() / d);
        let scale = (d as f64).powf(-0.5);
        let mut slots = self.initial_slots.clone();
        for _ in 0..self.iters {
            let q = self.to_q.forward(&self.norm_slots.apply(&slots));
            // dots [slots, inputs]: the softmax runs down each column (over the slots).
            let dots = linear(&q, slots_n, d, &k, tokens, None, Activation::None, None);
            let attn = softmax(&dots, tokens, Axis::Columns, scale, SLOT_ATTENTION_EPS);
            let updates = mix_rows(&normalize_rows(&attn, tokens), tokens, &v, d);
            let gates = (self.gru_input.forward(&updates), self.gru_hidden.forward(&slots));
            let next = gru_cell(&gates.0, &gates.1, &slots, d);
            let hidden = self.mlp.0.apply(&self.norm_pre_mlp.apply(&next), Activation::Relu, None);
            slots = self.mlp.1.apply(&hidden, Activation::None, Some(&next));
        }
        slots
    }
}

impl MixingBlock {
    fn read(r: &Reader, m: &EngineMixingBlock) -> MixingBlock {
        MixingBlock {
            to_q: r.dense(&m.to_q),
            to_k: r.dense(&m.to_k),
            norms: m.norms.as_ref().map(|(n1, n2)| (r.norm(n1), r.norm(n2))),
        }
    }

    /// The mixing weights `[rows, slots]` of the queries `x` `[rows, query_dim]`, from the keys
    /// `to_k(slots)` `[slots, att_dim]`.
    fn weights(&self, x: Vec<f64>, keys: &[f64]) -> Vec<f64> {
        let x = match &self.norms {
            Some((norm1, _)) => norm1.apply(&x),
            None => x,
        };
        let q = self.to_q.forward(&x);
        let att_dim = self.to_q.n;
        let (rows, slots) = (q.len() / att_dim, keys.len() / att_dim);
        let dots = linear(&q, rows, att_dim, keys, slots, None, Activation::None, None);
        softmax(&dots, slots, Axis::Rows, (att_dim as f64).powf(-0.5), 0.0)
    }

    /// The slot mix `Σ_s w·slots` `[rows, slot_dim]` (LayerNormed by `norm2` when configured).
    fn slot_mix(&self, weights: &[f64], slots: &[f64], slot_dim: usize) -> Vec<f64> {
        let mix = mix_rows(weights, slots.len() / slot_dim, slots, slot_dim);
        match &self.norms {
            Some((_, norm2)) => norm2.apply(&mix),
            None => mix,
        }
    }
}

impl RenderMlp {
    fn forward(&self, x: Vec<f64>) -> Vec<f64> {
        let (last, hidden) = self.layers.split_last().expect("render_mlp has five layers");
        let x = hidden.iter().fold(x, |x, lin| leaky_relu(lin.forward(&x), OUT_MLP_SLOPE));
        let out = last.forward(&x);
        if self.final_leaky_relu {
            leaky_relu(out, OUT_MLP_SLOPE)
        } else {
            out
        }
    }
}

impl SlotMixer {
    /// `SlotMixerDecoder` on query rows: the allocation transformer on the queries after the input MLP, the
    /// mixing weights over the slots, the render MLP on cat(slot mix, queries). Returns the render MLP's
    /// output `[rows, out_dims]` and the weights `[rows, slots]`.
    pub(super) fn decode(&self, scene: &ReferenceScene, q: &QueryRows) -> (Vec<f64>, Vec<f64>) {
        let at = &self.allocation_transformer;
        let queries = at.queries(q);
        let x = at.attend(queries.clone(), scene);
        let keys = scene.mixing_keys.as_deref().expect("an OSRT scene holds the mixing keys");
        let weights = self.mixing_block.weights(x, keys);
        let slot_dim = scene.latent.len() / scene.tokens;
        let mix = self.mixing_block.slot_mix(&weights, &scene.latent, slot_dim);
        let input = concat_columns(&mix, slot_dim, &queries, queries.len() / q.rows());
        (self.render_mlp.forward(input), weights)
    }
}
