//! OSRT and RP-OSRT (`base: osrt`), as the official modules build them (tberriel/RayPatchQuerying
//! `src/encoder.py` `OSRTEncoder`, `src/layers.py` `SlotAttention`, `src/decoder.py` `SlotMixerDecoder`/
//! `MixingBlock`/`RenderMLP`, `src/model.py` `OSRT`): posed images → the SRT encoder → set latent → slot
//! attention → slots; ray queries → allocation transformer (cross-attention to the slots) → mixing weights
//! over the slots (the segmentation) → slot mix → render MLP on cat(slot mix, queries) → per-ray colour (OSRT)
//! or patch features for the Ray-Patch decoder (RP-OSRT).

use raypatch_model::{OsrtConfig, TargetGrid};

use super::ray_patch::{bilinear_output, bilinear_patch_span, RayPatchDecoder};
use super::srt::{RayPredictor, SrtEncoder, OUT_MLP_SLOPE};
use super::{
    image_output_set, image_outputs, in_query_chunks, target_queries, wants_image, Encoded, LightField, QueryRows,
};
use crate::error::Result;
use crate::frame::{Output, Outputs};
use crate::graph::{Graph, ImageSize, Tensor};
use crate::kernels::concat::concat_columns;
use crate::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
use crate::kernels::mix::{mix_rows, MixArgs};
use crate::kernels::softmax::{softmax, Axis, SoftmaxArgs};
use crate::kernels::Activation;
use crate::nn::{product_t, LayerNorm, Linear, SlotAttention, Vars};
use crate::tensor::GpuTensor;

/// `OSRTEncoder`: the SRT encoder, then slot attention over its tokens.
pub struct OsrtEncoder {
    pub srt_encoder: SrtEncoder,
    pub slot_attention: SlotAttention,
}

/// `MixingBlock`: `w = softmax_slots(to_q(x)·to_k(slots)ᵀ·att_dim^-0.5)`, `s = Σ w·slots`, with optional
/// LayerNorms on x (`norm1`) and on s (`norm2`).
pub struct MixingBlock {
    pub path: String,
    pub to_q: Linear,
    pub to_k: Linear,
    pub norms: Option<(LayerNorm, LayerNorm)>,
    pub att_dim: usize,
}

/// `RenderMLP`: four Linear + LeakyReLU(0.01) layers, then the output layer (`net.0, 2, 4, 6, 8`), followed by
/// a LeakyReLU when it emits Ray-Patch features rather than rgb.
pub struct RenderMlp {
    pub layers: Vec<Linear>,
    pub final_activation: Activation,
}

/// `SlotMixerDecoder` (`decoder_att`).
pub struct SlotMixerDecoder {
    pub allocation_transformer: RayPredictor,
    pub mixing_block: MixingBlock,
    pub render_mlp: RenderMlp,
    pub num_slots: usize,
    /// The widest intermediate row of a query (sizes the query chunks).
    widest: usize,
}

/// OSRT, or RP-OSRT when `ray_patch` is set.
pub struct Osrt {
    pub config: OsrtConfig,
    pub encoder: OsrtEncoder,
    pub decoder: SlotMixerDecoder,
    pub ray_patch: Option<RayPatchDecoder>,
}

/// What one query chunk of the slot mixer writes: the mixing weights, and the render MLP's output when the
/// image is wanted.
struct ChunkOutputs {
    weights: Tensor,
    image: Option<Tensor>,
}

/// The scene tensors a render reads, in `Encoded::cached` order: each allocation layer's keys and values, the
/// mixing block's keys `to_k(slots)`, the slots.
struct SceneTensors {
    kv: Vec<Tensor>,
    mixing_keys: Tensor,
    slots: Tensor,
}

impl MixingBlock {
    fn new(vars: &Vars, c: &OsrtConfig) -> Result<Self> {
        let (d, slot_dim) = (&c.decoder, c.slot_attention.slot_dim);
        let norms = if d.layer_norm {
            Some((LayerNorm::new(&vars.pp("norm1"), c.query_dim())?, LayerNorm::new(&vars.pp("norm2"), slot_dim)?))
        } else {
            None
        };
        Ok(MixingBlock {
            path: vars.path().to_string(),
            to_q: Linear::no_bias(&vars.pp("to_q"), c.query_dim(), d.att_dim)?,
            to_k: Linear::no_bias(&vars.pp("to_k"), slot_dim, d.att_dim)?,
            norms,
            att_dim: d.att_dim,
        })
    }

    /// The mixing weights `[rows, slots]` of the queries `x` into `weights`.
    fn weights_into(&self, g: &mut Graph, x: Tensor, keys: Tensor, weights: Tensor) {
        let x = match &self.norms {
            Some((norm1, _)) => norm1.forward(g, x),
            None => x,
        };
        let q = self.to_q.forward(g, x, Activation::None);
        let dots = product_t(g, &format!("{}.dots", self.path), q, keys);
        let label = g.label(&format!("{}.weights", self.path));
        let scale = (self.att_dim as f32).powf(-0.5);
        softmax(&mut g.b, &label, SoftmaxArgs { x: dots.view, out: weights.view, axis: Axis::Rows, scale, eps: 0.0 });
    }

    /// The slot mix `Σ_s w·slots` `[rows, slot_dim]` (LayerNormed when configured).
    fn slot_mix(&self, g: &mut Graph, weights: Tensor, slots: Tensor) -> Tensor {
        let mix = g.transient(&format!("{}.slot_mix", self.path), weights.rows(), slots.cols);
        let label = g.label(&format!("{}.slot_mix", self.path));
        mix_rows(&mut g.b, &label, MixArgs { w: weights.view, x: slots.id(), out: mix.view });
        match &self.norms {
            Some((_, norm2)) => norm2.forward(g, mix),
            None => mix,
        }
    }
}

impl RenderMlp {
    fn new(vars: &Vars, input: usize, hidden: usize, out: usize) -> Result<Self> {
        let net = vars.pp("net");
        let layers =
            [(0, input, hidden), (2, hidden, hidden), (4, hidden, hidden), (6, hidden, hidden), (8, hidden, out)]
                .into_iter()
                .map(|(i, inp, out)| Linear::new(&net.pp(i), inp, out))
                .collect::<Result<Vec<_>>>()?;
        // `nn.Identity() if out_dim == 3 else nn.LeakyReLU()`.
        let final_activation = if out == 3 { Activation::None } else { Activation::LeakyRelu(OUT_MLP_SLOPE) };
        Ok(RenderMlp { layers, final_activation })
    }

    fn out_dim(&self) -> usize {
        self.layers.last().map_or(0, |l| l.out_dim)
    }

    fn forward_into(&self, g: &mut Graph, x: Tensor, out: Tensor) {
        let (last, hidden_layers) = self.layers.split_last().expect("render_mlp has five layers");
        let h = hidden_layers.iter().fold(x, |h, lin| lin.forward(g, h, Activation::LeakyRelu(OUT_MLP_SLOPE)));
        last.forward_into(g, h, out, self.final_activation, false);
    }
}

impl SlotMixerDecoder {
    fn new(vars: &Vars, c: &OsrtConfig) -> Result<Self> {
        let d = &c.decoder;
        let allocation = vars.pp("allocation_transformer");
        let (q, slot_dim) = (c.query_dim(), c.slot_attention.slot_dim);
        let widest = [RayPredictor::widest(&d.allocation), d.render_hidden, slot_dim + q, d.att_dim];
        Ok(SlotMixerDecoder {
            allocation_transformer: RayPredictor::new(&allocation, &allocation, &d.allocation)?,
            mixing_block: MixingBlock::new(&vars.pp("mixing_block"), c)?,
            render_mlp: RenderMlp::new(&vars.pp("render_mlp"), slot_dim + q, d.render_hidden, d.out_dims)?,
            num_slots: c.slot_attention.num_slots,
            widest: widest.into_iter().max().unwrap_or(1),
        })
    }

    /// The decoder on query rows `q`: the mixing weights into `out.weights`, and the render MLP's output into
    /// `out.image` when it is wanted.
    fn forward(&self, g: &mut Graph, q: QueryRows, scene: &SceneTensors, out: ChunkOutputs) {
        let at = &self.allocation_transformer;
        let queries = at.queries(g, q);
        // The transformer works in place; the render MLP needs the queries as they were (a bit-exact copy).
        let x = g.transient("decoder_att.allocation_transformer.x", queries.rows(), queries.cols);
        let label = g.label("decoder_att.allocation_transformer.x");
        map_columns(&mut g.b, &label, MapColumnsArgs { x: queries.view, col: 0, out: x.view, map: Map::Identity });
        at.transformer.forward_cross(g, x, &scene.kv);
        self.mixing_block.weights_into(g, x, scene.mixing_keys, out.weights);
        if let Some(image) = out.image {
            let mix = self.mixing_block.slot_mix(g, out.weights, scene.slots);
            let input = g.transient("decoder_att.render_mlp.input", mix.rows(), mix.cols + queries.cols);
            let label = g.label("decoder_att.render_mlp.input");
            concat_columns(&mut g.b, &label, mix.view, queries.view, input.view);
            self.render_mlp.forward_into(g, input, image);
        }
    }
}

impl Osrt {
    /// The module tree of `config` at `vars` (the model's root).
    pub fn new(vars: &Vars, config: &OsrtConfig) -> Result<Osrt> {
        let encoder = vars.pp("encoder");
        Ok(Osrt {
            encoder: OsrtEncoder {
                srt_encoder: SrtEncoder::new(&encoder.pp("srt_encoder"), &config.encoder)?,
                slot_attention: SlotAttention::new(
                    &encoder.pp("slot_attention"),
                    &config.slot_attention,
                    config.encoder.token_dim,
                )?,
            },
            decoder: SlotMixerDecoder::new(&vars.pp("decoder_att"), config)?,
            ray_patch: config
                .ray_patch
                .as_ref()
                .map(|rp| RayPatchDecoder::new(&vars.pp("decoder_rp.conv_decoder"), rp))
                .transpose()?,
            config: config.clone(),
        })
    }
}

impl LightField for Osrt {
    fn outputs(&self) -> Outputs {
        image_output_set(self.config.image_channels()).with(Output::Segmentation)
    }

    fn patch_size(&self) -> usize {
        self.config.patch_size()
    }

    fn patch_span(&self, lo: usize, hi: usize, patches: usize) -> (usize, usize) {
        match &self.ray_patch {
            // The image's conv decoder, and the bilinear resize of the segmentation.
            Some(rp) => {
                let (a, b) = rp.patch_span(lo, hi, patches);
                let (c, d) = bilinear_patch_span(lo, hi, patches, self.patch_size());
                (a.min(c), b.max(d))
            }
            None => (lo, hi),
        }
    }

    fn encode(&self, g: &mut Graph, size: ImageSize) -> Encoded {
        let set_latent = self.encoder.srt_encoder.forward(g, size, "set_latent");
        let sa = &self.encoder.slot_attention;
        let slots = g.output("latent", sa.num_slots, sa.slot_dim);
        sa.forward_into(g, set_latent, slots);
        // Everything of the decoder that depends only on the slots, once per scene.
        let transformer = &self.decoder.allocation_transformer.transformer;
        let mut cached: Vec<Tensor> = (0..transformer.layers.len())
            .map(|l| g.output(&format!("decoder.layers.{l}.kv"), slots.rows(), transformer.kv_width()))
            .collect();
        transformer.keys_values(g, slots, &cached);
        let mixing = &self.decoder.mixing_block;
        let keys = g.output("decoder.mixing_block.keys", slots.rows(), mixing.att_dim);
        mixing.to_k.forward_into(g, slots, keys, Activation::None, false);
        cached.extend([keys, slots]);
        Encoded { latent: slots, cached }
    }

    fn render(
        &self,
        g: &mut Graph,
        scene: &[GpuTensor],
        views: usize,
        grid: TargetGrid,
        outputs: Outputs,
    ) -> Vec<(Output, Tensor)> {
        let (queries, patches) = target_queries(g, self.ray_patch.as_ref(), self.patch_size(), views, grid);
        let layers = scene.len() - 2;
        let scene = SceneTensors {
            kv: (0..layers).map(|l| g.scene_tensor(&format!("decoder.layers.{l}.kv"), &scene[l])).collect(),
            mixing_keys: g.scene_tensor("decoder.mixing_block.keys", &scene[layers]),
            slots: g.scene_tensor("latent", &scene[layers + 1]),
        };
        let slots = self.decoder.num_slots;
        let (want_image, want_segmentation) = (wants_image(outputs), outputs.contains(Output::Segmentation));
        // Per-query weights for the whole grid when they are read back (directly the output for OSRT), else
        // per chunk.
        let weights = match (want_segmentation, &self.ray_patch) {
            (false, _) => None,
            (true, None) => Some(g.output(Output::Segmentation.name(), patches.pixels(), slots)),
            (true, Some(_)) => Some(g.image("decoder_att.mixing_block.weights", patches, slots)),
        };
        let features = want_image.then(|| g.image("decoder_features", patches, self.decoder.render_mlp.out_dim()));
        in_query_chunks(g, patches.pixels(), self.decoder.widest, |g, start, rows| {
            let weights = match weights {
                Some(w) => w.slice(start, rows),
                None => g.transient("decoder_att.mixing_block.weights", rows, slots),
            };
            let out = ChunkOutputs { weights, image: features.map(|f| f.slice(start, rows)) };
            self.decoder.forward(g, queries.slice(start, rows), &scene, out)
        });
        let mut rendered = match features {
            Some(features) => {
                let image = match &self.ray_patch {
                    Some(rp) => rp.forward(g, features, (grid.height, grid.width)),
                    None => features,
                };
                image_outputs(g, image, outputs)
            }
            None => Vec::new(),
        };
        if let Some(weights) = weights {
            let segmentation = match &self.ray_patch {
                // The official OSRT.decoder in eval mode: the patch weights bilinearly resized to the image, not
                // renormalised.
                Some(_) => {
                    let size = ImageSize { n: views, h: grid.height, w: grid.width };
                    bilinear_output(g, Output::Segmentation.name(), weights, size)
                }
                None => weights,
            };
            rendered.push((Output::Segmentation, segmentation));
        }
        rendered
    }
}
