//! Float64 CPU reference of the whole model, SRT / RP-SRT, OSRT / RP-OSRT and DeFiNe / RP-DeFiNe, composed
//! from the kernel references of this module and computing what `models/` records, op for op (the official
//! `SRTEncoder`, `SRTDecoder`, `OSRTEncoder`, `SlotMixerDecoder`, `DeFiNeEncoder`, `DeFiNeDecoder` and
//! `RayPatchDecoder`). The benchmark harness measures the engine's error against it, and the numerical stress
//! suite renders extreme scenes with both. It matches a float64 PyTorch run of the official model (`*_f64` in
//! the golden files) to ~1e-12 with [`Argument::Float64`].
//!
//! Laid out like the engine's `models/`: this file holds the float64 layers every family shares (a
//! transformer layer serves SRT's, OSRT's and the Perceiver's), the model (read through the engine's module
//! tree) and the render pipeline; `srt.rs` the SRT encoder, the ray predictor (the SRT decoder's and OSRT's
//! allocation transformer) and the SRT decoder; `osrt.rs` slot attention and the slot mixer decoder;
//! `define.rs` DeFiNe's ResNet-18 and Perceiver encoder and its two decoder heads; `ray_patch.rs` the patch
//! rays and the Ray-Patch conv decoder.
//!
//! The positional-encoding arguments are the one place where the float32 model differs from the float64 one
//! by more than rounding (up to ~1e-3 in rgb): choose [`Argument::RoundedToF32`] to measure the arithmetic
//! error of a float32 engine (its arguments are rounded as torch rounds them), [`Argument::Float64`] to
//! measure its distance from the float64 model. (The rays resized for patch rays or DeFiNe's encoder, and
//! DeFiNe's ImageNet normalisation, follow the same choice: float32 as torch and the engine form them, or
//! float64.)

mod define;
mod osrt;
mod ray_patch;
mod srt;

use raypatch_model::{Family, InputViews, LoadedModel, ModelConfig, ModelError, RaySource, TargetViews};

use raypatch_engine::error::EngineError;
use raypatch_engine::graph::Param;
use raypatch_engine::kernels::elementwise::Map;
use raypatch_engine::kernels::Activation;
use raypatch_engine::kernels::{conv_output_size, ConvMode};
use raypatch_engine::nn::{self, transformer::Projections as EngineProjections, Source, WeightSet};

use super::attention::attention;
use super::concat::concat_columns;
use super::conv::conv2d;
use super::elementwise::map_columns;
use super::matmul::linear;
use super::norm::layernorm;
use super::posenc::fourier_encode_with;
pub use super::posenc::Argument;
use super::resize::nearest;

/// LayerNorm eps of the official modules (PyTorch's default), as `nn::norm` uses it.
const LAYER_NORM_EPS: f64 = 1e-5;
/// The LeakyReLU slope of the SRT out MLP and the OSRT render MLP (`nn.LeakyReLU()`) as float64 torch has
/// it: the kernels' `Activation` holds an f32 slope, 2e-8 away from 0.01 relatively, so the reference applies
/// its slopes itself.
const OUT_MLP_SLOPE: f64 = 0.01;
/// Decoder queries per chunk: bounds the reference's memory at any resolution.
const QUERY_CHUNK: usize = 4096;

/// nn.Linear in float64: weight `[n, k]`, optional bias `[n]`.
struct Dense {
    w: Vec<f64>,
    b: Option<Vec<f64>>,
    n: usize,
    k: usize,
}

impl Dense {
    /// `act(x · wᵀ + b) (+ residual)` for `m` rows of x, the rows split over the CPU's threads.
    fn apply(&self, x: &[f64], act: Activation, residual: Option<&[f64]>) -> Vec<f64> {
        let m = x.len() / self.k;
        parallel_rows(m, self.n, |rows| {
            let residual = residual.map(|r| &r[rows.start * self.n..rows.end * self.n]);
            let x = &x[rows.start * self.k..rows.end * self.k];
            linear(x, rows.len(), self.k, &self.w, self.n, self.b.as_deref(), act, residual)
        })
    }

    /// `x · wᵀ + b`.
    fn forward(&self, x: &[f64]) -> Vec<f64> {
        self.apply(x, Activation::None, None)
    }
}

/// nn.LayerNorm in float64.
struct Norm {
    gamma: Vec<f64>,
    beta: Vec<f64>,
}

impl Norm {
    fn apply(&self, x: &[f64]) -> Vec<f64> {
        layernorm(x, self.gamma.len(), &self.gamma, &self.beta, LAYER_NORM_EPS)
    }
}

/// A convolution (PyTorch layout `[cout, cin, k, k]`) with its eval-mode BatchNorm folded in (by
/// `nn::Conv2d`, in float64).
struct Conv {
    w: Vec<f64>,
    b: Option<Vec<f64>>,
    spec: nn::ConvSpec,
}

impl Conv {
    /// The output size for an `h × w` input.
    fn output_size(&self, h: usize, w: usize) -> (usize, usize) {
        let nn::ConvSpec { window, upsample_input, .. } = self.spec;
        conv_output_size(h, w, window, upsample_input).expect("conv reference: the window does not fit")
    }

    /// `act(conv(x) + b)`, or with `residual` `(mode, r)` that met as `mode` says: `r + act(conv(x) + b)`
    /// ([`ConvMode::Accumulate`]) or `act(r + conv(x) + b)` ([`ConvMode::Residual`]). `stride` and
    /// `upsample_input` are checked against the module.
    #[allow(clippy::too_many_arguments)]
    fn apply(
        &self,
        x: &[f64],
        (n, h, w): (usize, usize, usize),
        stride: usize,
        upsample_input: bool,
        act: Activation,
        residual: Option<(ConvMode, &[f64])>,
    ) -> Vec<f64> {
        let nn::ConvSpec { cin, cout, window, .. } = self.spec;
        let module = (window.stride, self.spec.upsample_input);
        assert_eq!((stride, upsample_input), module, "conv reference: not the module's stride and upsampling");
        let (ho, wo) = self.output_size(h, w);
        let (mut out, mode) = match residual {
            Some((mode, r)) => (r.to_vec(), mode),
            None => (vec![0.0; n * ho * wo * cout], ConvMode::Overwrite),
        };
        conv2d(x, (n, h, w), cin, &self.w, self.b.as_deref(), cout, window, upsample_input, act, mode, &mut out);
        out
    }
}

/// The attention projections of a transformer layer.
enum Projections {
    SelfAttention { to_qkv: Dense },
    Cross { to_q: Dense, to_kv: Dense },
}

/// One pre-norm transformer layer (the official `Transformer`): `x + to_out(attention(LN(x)))`, then
/// `x + FF(LN(x))`. HuggingFace's `PerceiverLayer` is the same layer with its keys and values read from
/// `LN2(inputs)` in cross-attention (`kv_norm`), its query residual optional, and its q/k/v projections
/// stacked into `to_qkv` / `to_kv`.
struct Layer {
    attn_norm: Norm,
    /// The Perceiver's `layernorm2` on a cross-attention's inputs.
    kv_norm: Option<Norm>,
    projections: Projections,
    to_out: Dense,
    ff_norm: Norm,
    ff_in: Dense,
    ff_out: Dense,
    heads: usize,
    dim_head: usize,
    /// `to_out(attention) + x` (every layer but the Perceiver decoders').
    query_residual: bool,
}

impl Layer {
    fn inner(&self) -> usize {
        self.heads * self.dim_head
    }

    fn scale(&self) -> f64 {
        (self.dim_head as f64).powf(-0.5)
    }

    /// A self-attention layer on `[tokens, dim]`.
    fn self_attend(&self, z: &[f64]) -> Vec<f64> {
        let Projections::SelfAttention { to_qkv } = &self.projections else {
            panic!("self_attend on a cross-attention layer")
        };
        let (inner, ld) = (self.inner(), 3 * self.inner());
        let qkv = to_qkv.forward(&self.attn_norm.apply(z));
        let tokens = qkv.len() / ld;
        let heads = parallel_rows(tokens, inner, |rows| {
            let q = &qkv[rows.start * ld..rows.end * ld];
            let (h, dh) = (self.heads, self.dim_head);
            attention(q, ld, 0, &qkv, ld, inner, &qkv, ld, 2 * inner, rows.len(), tokens, h, dh, self.scale())
        });
        self.feed_forward(self.to_out.apply(&heads, Activation::None, Some(z)))
    }

    /// `to_kv(latent)` `[tokens, 2·inner]` (of `kv_norm(latent)` with one): what a cross-attention layer
    /// reads of the latent.
    fn keys_values(&self, latent: &[f64]) -> Vec<f64> {
        let Projections::Cross { to_kv, .. } = &self.projections else {
            panic!("keys_values of a self-attention layer")
        };
        match &self.kv_norm {
            Some(norm) => to_kv.forward(&norm.apply(latent)),
            None => to_kv.forward(latent),
        }
    }

    /// A cross-attention layer on queries `[rows, dim]`, reading `kv` from [`keys_values`](Self::keys_values).
    fn cross_attend(&self, x: &[f64], kv: &[f64]) -> Vec<f64> {
        let Projections::Cross { to_q, .. } = &self.projections else {
            panic!("cross_attend on a self-attention layer")
        };
        let (inner, ld) = (self.inner(), 2 * self.inner());
        let q = to_q.forward(&self.attn_norm.apply(x));
        let (rows, tokens) = (q.len() / inner, kv.len() / ld);
        let heads = parallel_rows(rows, inner, |r| {
            let q = &q[r.start * inner..r.end * inner];
            let (h, dh) = (self.heads, self.dim_head);
            attention(q, inner, 0, kv, ld, 0, kv, ld, inner, r.len(), tokens, h, dh, self.scale())
        });
        let residual = self.query_residual.then_some(x);
        self.feed_forward(self.to_out.apply(&heads, Activation::None, residual))
    }

    /// x + FF(LN(x)), FF = Linear → GELU → Linear.
    fn feed_forward(&self, x: Vec<f64>) -> Vec<f64> {
        let hidden = self.ff_in.apply(&self.ff_norm.apply(&x), Activation::Gelu, None);
        self.ff_out.apply(&hidden, Activation::None, Some(&x))
    }
}

/// The official `PositionalEncoding` with its f32 multipliers, the arguments formed as `argument` says.
struct Fourier {
    multipliers: Vec<f32>,
    argument: Argument,
}

impl Fourier {
    /// `rows` rows of the encoding, row r of coordinate row `(first_row + r) / repeat` of `coords` `[R, 3]`.
    fn encode(&self, coords: &[f64], repeat: usize, first_row: usize, rows: usize) -> Vec<f64> {
        fourier_encode_with(coords, repeat, first_row, rows, &self.multipliers, self.argument)
    }

    fn width(&self) -> usize {
        6 * self.multipliers.len()
    }
}

/// The official `RayEncoder` on query rows: `cat(posenc(camera position), posenc(ray))`, after the raw
/// `cat(ray, camera position)` with `raw` (as DeFiNe's encoder and decoders concatenate them).
struct RayEncoder {
    pos_enc: Fourier,
    ray_enc: Fourier,
    raw: bool,
}

impl RayEncoder {
    fn width(&self) -> usize {
        6 * usize::from(self.raw) + self.pos_enc.width() + self.ray_enc.width()
    }

    /// The features `[rows, width()]` of the query rows.
    fn forward(&self, q: &QueryRows) -> Vec<f64> {
        let rows = q.rows();
        let pos = self.pos_enc.encode(q.positions, q.per_view, q.start, rows);
        let ray = self.ray_enc.encode(q.rays, 1, 0, rows);
        let encoded = concat_columns(&pos, self.pos_enc.width(), &ray, self.ray_enc.width());
        if !self.raw {
            return encoded;
        }
        let raw: Vec<f64> = (0..rows)
            .flat_map(|r| q.rays[3 * r..3 * r + 3].iter().chain(&q.positions[(q.start + r) / q.per_view * 3..][..3]))
            .copied()
            .collect();
        concat_columns(&raw, 6, &encoded, self.width() - 6)
    }
}

/// Reads the engine's modules into the reference's float64 layers.
struct Reader<'w> {
    weights: &'w WeightSet,
    argument: Argument,
}

impl Reader<'_> {
    fn get(&self, p: Param) -> Vec<f64> {
        self.weights.get(p).data.to_f64()
    }

    fn dense(&self, l: &nn::Linear) -> Dense {
        Dense { w: self.get(l.weight), b: l.bias.map(|b| self.get(b)), n: l.out_dim, k: l.in_dim }
    }

    fn norm(&self, n: &nn::LayerNorm) -> Norm {
        Norm { gamma: self.get(n.gamma), beta: self.get(n.beta) }
    }

    fn conv(&self, c: &nn::Conv2d) -> Conv {
        Conv { w: self.get(c.weight), b: c.bias.map(|b| self.get(b)), spec: c.spec }
    }

    fn fourier(&self, f: &nn::FourierEncoding) -> Fourier {
        Fourier { multipliers: f.multipliers.clone(), argument: self.argument }
    }

    fn ray_encoder(&self, pos_enc: &nn::FourierEncoding, ray_enc: &nn::FourierEncoding, raw: bool) -> RayEncoder {
        RayEncoder { pos_enc: self.fourier(pos_enc), ray_enc: self.fourier(ray_enc), raw }
    }

    fn layers(&self, t: &nn::Transformer) -> Vec<Layer> {
        t.layers
            .iter()
            .map(|l| Layer {
                attn_norm: self.norm(&l.attn_norm),
                kv_norm: None,
                projections: match &l.attn.projections {
                    EngineProjections::SelfAttention { to_qkv } => {
                        Projections::SelfAttention { to_qkv: self.dense(to_qkv) }
                    }
                    EngineProjections::Cross { to_q, to_kv } => {
                        Projections::Cross { to_q: self.dense(to_q), to_kv: self.dense(to_kv) }
                    }
                },
                to_out: self.dense(&l.attn.to_out),
                ff_norm: self.norm(&l.ff_norm),
                ff_in: self.dense(&l.ff.net_0),
                ff_out: self.dense(&l.ff.net_3),
                heads: l.attn.heads,
                dim_head: l.attn.dim_head,
                query_residual: true,
            })
            .collect()
    }
}

/// The encoder of a model family: the SRT encoder (SRT, and OSRT beneath its slots) or DeFiNe's (one per
/// model: the variants' sizes do not matter).
#[allow(clippy::large_enum_variant)]
enum Encoder {
    Srt(srt::SrtEncoder),
    Define(define::DefineEncoder),
}

/// The decoder of a model family, with what the family adds to the SRT encoder (one per model: the variants'
/// sizes do not matter).
#[allow(clippy::large_enum_variant)]
enum Decoder {
    Srt(srt::SrtDecoder),
    Osrt(osrt::Osrt),
    Define(define::Heads),
}

/// What turns a decoder head's query features into its image: the Ray-Patch conv decoder, if any, and the
/// image's channels (SRT and OSRT: one head of 3, or 4 with log-depth; DeFiNe: rgb 3, then depth 1).
struct Head {
    channels: usize,
    ray_patch: Option<ray_patch::ConvDecoder>,
}

/// The whole model in float64, read from a [`LoadedModel`].
pub struct ReferenceModel {
    config: ModelConfig,
    argument: Argument,
    encoder: Encoder,
    decoder: Decoder,
    /// One per decoder head, in the decoder's order.
    heads: Vec<Head>,
}

/// A scene encoded by the reference.
pub struct ReferenceScene {
    /// The latent the decoder attends to: SRT's tokens `[tokens, token_dim]`, OSRT's slots
    /// `[slots, slot_dim]`, DeFiNe's latents `[num_latents, latent_dim]` (the engine's `latent` output).
    pub latent: Vec<f64>,
    /// Rows of `latent` (tokens, slots, or latents).
    pub tokens: usize,
    /// OSRT: the SRT encoder's tokens `[tokens, token_dim]` that slot attention reads (`set_latent`).
    pub set_latent: Option<Vec<f64>>,
    /// Per decoder cross-attention layer (DeFiNe: per head), `[tokens, 2·inner]`: keys, then values.
    pub keys_values: Vec<Vec<f64>>,
    /// OSRT: the mixing block's keys `to_k(slots)` `[slots, att_dim]`.
    mixing_keys: Option<Vec<f64>>,
}

/// Rendered target views in float64.
#[derive(Clone, Debug)]
pub struct ReferenceFrame {
    pub views: usize,
    pub height: usize,
    pub width: usize,
    /// `[views, height, width, 3]`, after the sigmoid.
    pub rgb: Vec<f64>,
    /// `[views, height, width]`, for models with a log-depth channel or head.
    pub logdepth: Option<Vec<f64>>,
    /// OSRT: the slot weights `[views, height, width, slots]` (for Ray-Patch, the patch rays' weights
    /// bilinearly resized to the image, not renormalised, as the official `OSRT.decoder` has them).
    pub segmentation: Option<Vec<f64>>,
    /// Slots per pixel of `segmentation` (0 without one).
    pub slots: usize,
}

/// Query rows `start..start + rays.len() / 3` of the target views (`per_view` a view): their rays, and the
/// camera positions `[views, 3]` they read.
struct QueryRows<'a> {
    positions: &'a [f64],
    per_view: usize,
    start: usize,
    rays: &'a [f64],
}

impl QueryRows<'_> {
    fn rows(&self) -> usize {
        self.rays.len() / 3
    }
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

impl ReferenceModel {
    /// Reads the model's weights through the engine's module tree (the same names, shapes and BatchNorm
    /// fold, in float64), into the reference's own float64 layers.
    pub fn new(model: &LoadedModel, argument: Argument) -> Result<ReferenceModel, EngineError> {
        let config = model.config.clone();
        let source = Source::File { model, limits: raypatch_engine::nn::ReadLimits::NONE };
        let (encoder, decoder, heads) = match &config.family {
            Family::Srt(c) => {
                let (m, weights) = nn::build(source, |vars| raypatch_engine::models::srt::Srt::new(vars, c))?;
                let r = Reader { weights: &weights, argument };
                let decoder = Decoder::Srt(srt::SrtDecoder::read(&r, &m.decoder));
                let head = Head { channels: c.image_channels(), ray_patch: r.ray_patch(&m.ray_patch) };
                (Encoder::Srt(srt::SrtEncoder::read(&r, &m.encoder)), decoder, vec![head])
            }
            Family::Osrt(c) => {
                let (m, weights) = nn::build(source, |vars| raypatch_engine::models::osrt::Osrt::new(vars, c))?;
                let r = Reader { weights: &weights, argument };
                let decoder = Decoder::Osrt(osrt::Osrt::read(&r, &m));
                let encoder = Encoder::Srt(srt::SrtEncoder::read(&r, &m.encoder.srt_encoder));
                (encoder, decoder, vec![Head { channels: c.image_channels(), ray_patch: r.ray_patch(&m.ray_patch) }])
            }
            Family::Define(c) => {
                let (m, weights) = nn::build(source, |vars| raypatch_engine::models::define::Define::new(vars, c))?;
                let r = Reader { weights: &weights, argument };
                let heads = m
                    .heads
                    .iter()
                    .map(|h| Head { channels: define::head_channels(h), ray_patch: r.ray_patch(&h.ray_patch) });
                let encoder = Encoder::Define(define::DefineEncoder::read(&r, &m.encoder));
                (encoder, Decoder::Define(define::Heads::read(&r, &m.heads)), heads.collect())
            }
        };
        Ok(ReferenceModel { config, argument, encoder, decoder, heads })
    }

    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// Encodes posed input views: the encoder's latent (SRT's tokens, DeFiNe's latents), OSRT's slots from
    /// it, and what the decoder reads of the latent (keys and values, and OSRT's mixing keys).
    pub fn encode(&self, inputs: &InputViews) -> Result<ReferenceScene, ModelError> {
        inputs.check("input views")?;
        Ok(match (&self.encoder, &self.decoder) {
            (Encoder::Srt(e), Decoder::Srt(d)) => {
                let z = e.forward(inputs);
                let tokens = z.len() / e.token_dim();
                d.scene(z, tokens)
            }
            (Encoder::Srt(e), Decoder::Osrt(o)) => o.scene(e.forward(inputs)),
            (Encoder::Define(e), Decoder::Define(d)) => d.scene(e.forward(inputs)?),
            _ => unreachable!("the encoder and decoder of one family"),
        })
    }

    /// Renders target views of an encoded scene: the decoder on every query (pixel, or patch for Ray-Patch),
    /// then per head the Ray-Patch decoder, then the output maps (the sigmoid; DeFiNe's log-depth); OSRT's
    /// segmentation beside. Patch rays are made from full-resolution rays as the official loader makes them
    /// (bilinear), in f32 with [`Argument::RoundedToF32`] (PyTorch's float32 operation order, which the
    /// engine reproduces bit for bit) and in f64 otherwise.
    pub fn render(&self, scene: &ReferenceScene, targets: &TargetViews) -> Result<ReferenceFrame, ModelError> {
        let k = self.config.patch_size();
        let grid = targets.grid_for(&self.config, "target views")?;
        let (views, ph, pw) = (targets.count, grid.height / k, grid.width / k);
        let rays = if k > 1 && grid.rays != RaySource::Patches {
            ray_patch::patch_rays(targets, ph, pw, self.argument)
        } else {
            f64s(&targets.ray_values())
        };
        let queries = views * ph * pw;
        let positions = f64s(&targets.camera_pos);
        let (mut features, mut weights) = (vec![Vec::new(); self.heads.len()], Vec::new());
        for start in (0..queries).step_by(QUERY_CHUNK) {
            let rows = QUERY_CHUNK.min(queries - start);
            let q = QueryRows {
                positions: &positions,
                per_view: ph * pw,
                start,
                rays: &rays[3 * start..3 * (start + rows)],
            };
            match &self.decoder {
                Decoder::Srt(d) => features[0].extend(d.decode(scene, &q)),
                Decoder::Osrt(o) => {
                    let (f, w) = o.decoder.decode(scene, &q);
                    features[0].extend(f);
                    weights.extend(w);
                }
                Decoder::Define(d) => {
                    for (h, f) in features.iter_mut().enumerate() {
                        f.extend(d.decode(h, scene, &q));
                    }
                }
            }
        }

        // Each head's image before its output map.
        let (height, width) = (grid.height, grid.width);
        let images: Vec<Vec<f64>> = features
            .into_iter()
            .zip(&self.heads)
            .map(|(features, head)| {
                let image = match &head.ray_patch {
                    None => features,
                    Some(rp) => rp.forward(features, views, ph, pw, head.channels),
                };
                // The official output resize (rp_kwargs h_out/w_out) when k does not divide the target size.
                if (ph * k, pw * k) == (height, width) {
                    image
                } else {
                    nearest(&image, views, ph * k, pw * k, head.channels, height, width)
                }
            })
            .collect();
        let (segmentation, slots) = match &self.decoder {
            Decoder::Osrt(_) => {
                let slots = scene.tokens;
                // Ray-Patch: the patch weights bilinearly resized to the image (the official OSRT.decoder).
                let resized = if k > 1 {
                    ray_patch::resize_bilinear(&weights, views, (ph, pw), slots, (height, width), self.argument)
                } else {
                    weights
                };
                (Some(resized), slots)
            }
            _ => (None, 0),
        };
        let channels = self.heads[0].channels;
        let logdepth = match &self.decoder {
            Decoder::Define(_) => Some(define::log_depth(&images[1])),
            _ => (channels == 4).then(|| map_columns(&images[0], channels, 3, 1, Map::Identity)),
        };
        Ok(ReferenceFrame {
            views,
            height,
            width,
            rgb: map_columns(&images[0], channels, 0, 3, Map::Sigmoid),
            logdepth,
            segmentation,
            slots,
        })
    }
}

fn leaky_relu(mut x: Vec<f64>, slope: f64) -> Vec<f64> {
    x.iter_mut().filter(|v| **v < 0.0).for_each(|v| *v *= slope);
    x
}

/// Computes `rows` rows of `cols` values, split into contiguous row ranges over the CPU's threads.
fn parallel_rows(rows: usize, cols: usize, f: impl Fn(std::ops::Range<usize>) -> Vec<f64> + Sync) -> Vec<f64> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(rows.div_ceil(16)).max(1);
    let per = rows.div_ceil(threads);
    let parts: Vec<Vec<f64>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                let range = (t * per).min(rows)..((t + 1) * per).min(rows);
                let f = &f;
                s.spawn(move || f(range))
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("reference thread panicked")).collect()
    });
    let mut out = Vec::with_capacity(rows * cols);
    parts.into_iter().for_each(|p| out.extend(p));
    out
}
