//! DeFiNe / RP-DeFiNe in float64 (`models/define.rs`, `nn/resnet.rs`, `nn/perceiver.rs`): the ImageNet
//! normalisation of the input images, the ResNet-18 features and the ray features → tokens, the
//! HuggingFace Perceiver encoder (learned latents, one cross-attention, self-attention layers), and the two
//! decoder heads (rgb, depth), each a Perceiver cross-attention to the latents without query residual and a
//! final layer. RP-DeFiNe's per-head Ray-Patch decoders and the render are `mod.rs`'s.

use raypatch_model::config::define::{DEPTH_MAX, DEPTH_MIN};
use raypatch_model::{InputViews, ModelError};

use super::ray_patch::{resize_bilinear, resized_rays};
use super::{f64s, Argument, Conv, Dense, Layer, Projections, QueryRows, RayEncoder, Reader, ReferenceScene};
use crate::concat::concat_columns;
use crate::pool::max_pool2d;
use raypatch_engine::graph::ChannelNorm;
use raypatch_engine::kernels::pool::pool_output_size;
use raypatch_engine::kernels::ConvMode;
use raypatch_engine::kernels::{Activation, Window};
use raypatch_engine::models::define::{
    DefineEncoder as EngineDefineEncoder, Head as EngineHead, RayEncoder as EngineRayEncoder, IMAGENET,
};
use raypatch_engine::nn::{self, resnet::BasicBlock as EngineBasicBlock};

/// torchvision `BasicBlock`: `relu(bn2(conv2(relu(bn1(conv1(x))))) + identity)`, the identity `downsample(x)`
/// where there is one; BatchNorms folded.
struct BasicBlock {
    conv1: Conv,
    conv2: Conv,
    downsample: Option<Conv>,
}

/// The official `ResNetSkip` (ResNet-18 without avgpool and fc): stem conv → ReLU → max pool, four stages of
/// two blocks, each stage's output returned.
struct ResNet18 {
    conv1: Conv,
    maxpool: Window,
    layers: Vec<[BasicBlock; 2]>,
}

/// An NHWC feature map of `n` images, `[n·h·w, channels]`.
struct FeatureMap {
    x: Vec<f64>,
    h: usize,
    w: usize,
    channels: usize,
}

/// `DeFiNeEncoder`: the ResNet, the ray features and the Perceiver.
pub(super) struct DefineEncoder {
    ray_encoder: RayEncoder,
    conv_blocks: ResNet18,
    /// `transformer.embeddings.latents` `[num_latents, latent_dim]`.
    latents: Vec<f64>,
    cross_attention: Layer,
    self_attends: Vec<Layer>,
    argument: Argument,
}

/// `DeFiNeDecoder` (`decoder_att_rgb`, `decoder_att_d`): the query features, the `PerceiverBasicDecoder`'s
/// cross-attention to the latents (no query residual) and its `final_layer`.
struct DefineDecoder {
    query_encoder: RayEncoder,
    cross_attention: Layer,
    final_layer: Dense,
}

/// The decoders of the heads, rgb then depth.
pub(super) struct Heads {
    decoders: Vec<DefineDecoder>,
    latent_dim: usize,
}

/// The f64 value of a decimal constant the engine holds as f32 (the ImageNet statistics, the depth range):
/// its shortest decimal form, which is the literal float64 torch uses (`0.485f32` → `0.485`).
fn decimal(v: f32) -> f64 {
    v.to_string().parse().expect("an f32 prints as a decimal")
}

/// torchvision's `Normalize(mean, std)` of input RGB `[pixels, 3]` in [0, 1]: `(x − mean) / std` in f32
/// as the engine's host and float32 torch compute it ([`Argument::RoundedToF32`]), or in f64.
fn imagenet_normalize(images: &[f32], argument: Argument) -> Vec<f64> {
    let ChannelNorm { mean, std } = IMAGENET;
    let (mean64, std64) = (mean.map(decimal), std.map(decimal));
    let channel = |(i, &v): (usize, &f32)| match argument {
        Argument::RoundedToF32 => f64::from((v - mean[i % 3]) / std[i % 3]),
        Argument::Float64 => (f64::from(v) - mean64[i % 3]) / std64[i % 3],
    };
    images.iter().enumerate().map(channel).collect()
}

/// The official log-depth of the depth head's image: `log(sigmoid(x)·(d_max − d_min) + d_min)`, in f64 as
/// float64 torch has it (the engine's `Map::LogSigmoidAffine` holds f32 constants).
pub(super) fn log_depth(x: &[f64]) -> Vec<f64> {
    let (min, max) = (decimal(DEPTH_MIN), decimal(DEPTH_MAX));
    x.iter().map(|&v| (1.0 / (1.0 + (-v).exp()) * (max - min) + min).ln()).collect()
}

/// One `nn.Linear` of the stacked outputs of `parts` (all reading the same input): PyTorch's separate
/// query, key and value projections as one `to_qkv` or `to_kv`, each output computed as before.
fn stacked(parts: &[Dense]) -> Dense {
    let k = parts[0].k;
    assert!(parts.iter().all(|d| d.k == k), "stacked projections read inputs of one width");
    let biased = parts.iter().any(|d| d.b.is_some());
    Dense {
        w: parts.iter().flat_map(|d| d.w.iter().copied()).collect(),
        b: biased.then(|| parts.iter().flat_map(|d| d.b.clone().unwrap_or_else(|| vec![0.0; d.n])).collect()),
        n: parts.iter().map(|d| d.n).sum(),
        k,
    }
}

impl Reader<'_> {
    /// HF's `PerceiverLayer` as a [`Layer`].
    fn perceiver(&self, l: &nn::PerceiverLayer) -> Layer {
        let value = match &l.value {
            nn::Values::Rows(linear) => self.dense(linear),
            // The same weight, read as data by the engine.
            nn::Values::Transposed { weight, bias, .. } => {
                let (n, k) = (l.dims.inner(), l.dims.kv_dim.unwrap_or(l.dims.q_dim));
                Dense { w: self.get(*weight), b: Some(self.get(*bias)), n, k }
            }
        };
        let (query, key) = (self.dense(&l.query), self.dense(&l.key));
        let projections = match l.dims.kv_dim {
            Some(_) => Projections::Cross { to_q: query, to_kv: stacked(&[key, value]) },
            None => Projections::SelfAttention { to_qkv: stacked(&[query, key, value]) },
        };
        Layer {
            attn_norm: self.norm(&l.layernorm1),
            kv_norm: l.layernorm2.as_ref().map(|n| self.norm(n)),
            projections,
            to_out: self.dense(&l.output),
            ff_norm: self.norm(&l.layernorm),
            ff_in: self.dense(&l.dense1),
            ff_out: self.dense(&l.dense2),
            heads: l.dims.heads,
            dim_head: l.dims.inner() / l.dims.heads,
            query_residual: l.dims.query_residual,
        }
    }

    /// DeFiNe's `RayEncoder`, after the raw ray and camera position.
    fn define_rays(&self, e: &EngineRayEncoder) -> RayEncoder {
        self.ray_encoder(&e.pos_enc, &e.ray_enc, true)
    }

    fn basic_block(&self, b: &EngineBasicBlock) -> BasicBlock {
        BasicBlock {
            conv1: self.conv(&b.conv1),
            conv2: self.conv(&b.conv2),
            downsample: b.downsample.as_ref().map(|d| self.conv(d)),
        }
    }
}

impl BasicBlock {
    /// The block on `x` `[n·h·w, cin]`, its first conv (and downsample) of stride `stride`.
    fn forward(&self, x: &FeatureMap, n: usize, stride: usize) -> FeatureMap {
        let dims = (n, x.h, x.w);
        let (h, w) = self.conv1.output_size(x.h, x.w);
        let hidden = self.conv1.apply(&x.x, dims, stride, false, Activation::Relu, None);
        let identity = match &self.downsample {
            Some(downsample) => downsample.apply(&x.x, dims, stride, false, Activation::None, None),
            None => x.x.clone(),
        };
        let residual = Some((ConvMode::Residual, identity.as_slice()));
        let out = self.conv2.apply(&hidden, (n, h, w), 1, false, Activation::Relu, residual);
        FeatureMap { x: out, h, w, channels: self.conv2.spec.cout }
    }
}

impl ResNet18 {
    /// The four stages' outputs of `n` normalised NHWC images `[n·h·w, 3]`.
    fn forward(&self, images: Vec<f64>, (n, h, w): (usize, usize, usize)) -> Vec<FeatureMap> {
        let (sh, sw) = self.conv1.output_size(h, w);
        let stem = self.conv1.apply(&images, (n, h, w), 2, false, Activation::Relu, None);
        let channels = self.conv1.spec.cout;
        let (ph, pw) = pool_output_size(sh, sw, self.maxpool).expect("max pool reference: the window does not fit");
        let pooled = max_pool2d(&stem, (n, sh, sw), channels, self.maxpool);
        let mut x = FeatureMap { x: pooled, h: ph, w: pw, channels };
        let mut outputs = Vec::with_capacity(self.layers.len());
        for (i, blocks) in self.layers.iter().enumerate() {
            x = blocks[0].forward(&x, n, if i == 0 { 1 } else { 2 });
            x = blocks[1].forward(&x, n, 1);
            outputs.push(FeatureMap { x: x.x.clone(), ..x });
        }
        outputs
    }
}

impl DefineEncoder {
    pub(super) fn read(r: &Reader, e: &EngineDefineEncoder) -> DefineEncoder {
        let resnet = &e.conv_blocks;
        DefineEncoder {
            ray_encoder: r.define_rays(&e.ray_encoder),
            conv_blocks: ResNet18 {
                conv1: r.conv(&resnet.conv1),
                maxpool: resnet.maxpool.window,
                layers: resnet.layers.iter().map(|l| [r.basic_block(&l[0]), r.basic_block(&l[1])]).collect(),
            },
            latents: r.get(e.latents),
            cross_attention: r.perceiver(&e.cross_attention),
            self_attends: e.self_attends.iter().map(|l| r.perceiver(l)).collect(),
            argument: r.argument,
        }
    }

    /// The latents `[num_latents, latent_dim]` of (checked) posed input views: the tokens
    /// `cat(x1, x2..x4 bilinearly resized to x1, ray, camera position, posenc(position), posenc(ray))` of
    /// the ResNet's features and the rays resized to H/4 × W/4, then the Perceiver.
    pub(super) fn forward(&self, inputs: &InputViews) -> Result<Vec<f64>, ModelError> {
        let (n, h, w) = (inputs.count, inputs.height, inputs.width);
        if !h.is_multiple_of(4) || !w.is_multiple_of(4) {
            return Err(ModelError::Value {
                path: "input views".into(),
                key: "input_images".into(),
                reason: format!("{w}x{h}: DeFiNe needs input sizes divisible by 4"),
            });
        }
        let features = self.conv_blocks.forward(imagenet_normalize(&inputs.images, self.argument), (n, h, w));
        let (gh, gw) = (features[0].h, features[0].w);
        let (mut tokens, mut cols) = (features[0].x.clone(), features[0].channels);
        for f in &features[1..] {
            let resized = resize_bilinear(&f.x, n, (f.h, f.w), f.channels, (gh, gw), self.argument);
            tokens = concat_columns(&tokens, cols, &resized, f.channels);
            cols += f.channels;
        }
        let rays = resized_rays(&inputs.rays, n, (h, w), (gh, gw), self.argument);
        let positions = f64s(&inputs.camera_pos);
        let q = QueryRows { positions: &positions, per_view: gh * gw, start: 0, rays: &rays };
        let tokens = concat_columns(&tokens, cols, &self.ray_encoder.forward(&q), self.ray_encoder.width());

        let latent = self.cross_attention.cross_attend(&self.latents, &self.cross_attention.keys_values(&tokens));
        Ok(self.self_attends.iter().fold(latent, |z, layer| layer.self_attend(&z)))
    }
}

/// The channels of a head's image: its Ray-Patch decoder's outputs, or its final layer's.
pub(super) fn head_channels(head: &EngineHead) -> usize {
    head.ray_patch.as_ref().map_or(head.decoder.final_layer.out_dim, |rp| rp.conv_0.spec.cout)
}

impl Heads {
    pub(super) fn read(r: &Reader, heads: &[EngineHead]) -> Heads {
        let decoders = heads
            .iter()
            .map(|h| DefineDecoder {
                query_encoder: r.define_rays(&h.decoder.query_encoder),
                cross_attention: r.perceiver(&h.decoder.cross_attention),
                final_layer: r.dense(&h.decoder.final_layer),
            })
            .collect();
        let latent_dim = heads[0].decoder.cross_attention.dims.kv_dim.expect("a decoder cross-attends");
        Heads { decoders, latent_dim }
    }

    /// The encoded scene of the latents: each head's keys and values of them.
    pub(super) fn scene(&self, latent: Vec<f64>) -> ReferenceScene {
        ReferenceScene {
            keys_values: self.decoders.iter().map(|d| d.cross_attention.keys_values(&latent)).collect(),
            tokens: latent.len() / self.latent_dim,
            latent,
            set_latent: None,
            mixing_keys: None,
        }
    }

    /// Head `head`'s decoder on query rows: `final_layer(cross_attention(cat(ray, position, posenc(position),
    /// posenc(ray)), latents))` `[rows, out_dims]`.
    pub(super) fn decode(&self, head: usize, scene: &ReferenceScene, q: &QueryRows) -> Vec<f64> {
        let d = &self.decoders[head];
        let x = d.cross_attention.cross_attend(&d.query_encoder.forward(q), &scene.keys_values[head]);
        d.final_layer.forward(&x)
    }
}
