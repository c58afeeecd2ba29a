//! Float64 CPU reference of the whole SRT / RP-SRT model, composed from the kernel references of this module
//! and computing what `models/srt.rs` records, op for op (the official `SRTEncoder`, `SRTDecoder` and
//! `RayPatchDecoder`). The benchmark harness measures the engine's error against it, and the numerical stress
//! suite renders extreme scenes with both. It matches a float64 PyTorch run of the official model
//! (`rgb_f64` in the golden files) to ~1e-12 with [`Argument::Float64`].
//!
//! The positional-encoding arguments are the one place where the float32 model differs from the float64 one
//! by more than rounding (up to ~1e-3 in rgb): choose [`Argument::RoundedToF32`] to measure the arithmetic
//! error of a float32 engine (its arguments are rounded as torch rounds them), [`Argument::Float64`] to
//! measure its distance from the float64 model.

use raypatch_model::{Family, InputViews, LoadedModel, ModelConfig, ModelError, Octaves, SrtConfig, TargetViews};

use crate::error::EngineError;
use crate::models::srt::Srt;
use crate::nn::{self, transformer::Projections, Param, Source};

use super::attention::attention;
use super::conv::conv3x3;
use super::elementwise::map_columns;
use super::matmul::linear;
use super::norm::layernorm;
use super::posenc::fourier_encode_with;
pub use super::posenc::Argument;
use super::resize::{bilinear, linear_source, nearest};
use crate::kernels::elementwise::Map;
use crate::kernels::{posenc::multipliers, Activation};

/// LayerNorm eps of the official modules (PyTorch's default), as `nn::norm` uses it.
const LAYER_NORM_EPS: f64 = 1e-5;
/// LeakyReLU slopes (out_mlp, Ray-Patch conv decoder) as float64 torch has them: the kernels' `Activation`
/// holds an f32 slope, 2e-8 away from 0.01 relatively, so the reference applies these itself.
const OUT_MLP_SLOPE: f64 = 0.01;
const CONV_DECODER_SLOPE: f64 = 0.2;
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
}

struct Norm {
    gamma: Vec<f64>,
    beta: Vec<f64>,
}

impl Norm {
    fn apply(&self, x: &[f64]) -> Vec<f64> {
        layernorm(x, self.gamma.len(), &self.gamma, &self.beta, LAYER_NORM_EPS)
    }
}

/// A 3×3 convolution (PyTorch layout `[cout, cin, 3, 3]`) with its eval-mode BatchNorm folded in (by
/// `nn::Conv3x3`, in float64).
struct Conv {
    w: Vec<f64>,
    b: Option<Vec<f64>>,
    cin: usize,
    cout: usize,
}

impl Conv {
    #[allow(clippy::too_many_arguments)]
    fn apply(
        &self,
        x: &[f64],
        (n, h, w): (usize, usize, usize),
        stride: usize,
        upsample_input: bool,
        act: Activation,
        residual: Option<&[f64]>,
    ) -> Vec<f64> {
        conv3x3(x, n, h, w, self.cin, &self.w, self.b.as_deref(), self.cout, stride, upsample_input, act, residual)
    }
}

/// One transformer layer: self-attention (`projections` = [to_qkv]) or cross-attention ([to_q, to_kv]).
struct Layer {
    attn_norm: Norm,
    projections: Vec<Dense>,
    to_out: Dense,
    ff_norm: Norm,
    ff_in: Dense,
    ff_out: Dense,
}

/// The whole model in float64, read from a [`LoadedModel`].
pub struct ReferenceModel {
    config: ModelConfig,
    srt: SrtConfig,
    argument: Argument,
    conv_blocks: Vec<(Conv, Conv)>,
    per_patch_linear: Dense,
    encoder_layers: Vec<Layer>,
    input_mlp: (Dense, Dense),
    decoder_layers: Vec<Layer>,
    out_mlp: Vec<Dense>,
    /// The Ray-Patch conv decoder: conv_0, then per block (feature conv, rgb conv).
    ray_patch: Option<(Conv, Vec<(Conv, Conv)>)>,
}

/// A scene encoded by the reference: the latent tokens and, per decoder layer, `to_kv(z)`.
pub struct ReferenceScene {
    /// `[tokens, token_dim]`.
    pub latent: Vec<f64>,
    pub tokens: usize,
    /// Per decoder layer, `[tokens, 2·inner]`: keys, then values.
    pub keys_values: Vec<Vec<f64>>,
}

/// Rendered target views in float64.
#[derive(Clone, Debug)]
pub struct ReferenceFrame {
    pub views: usize,
    pub height: usize,
    pub width: usize,
    /// `[views, height, width, 3]`, after the sigmoid.
    pub rgb: Vec<f64>,
    /// `[views, height, width]`, for models with a log-depth channel.
    pub logdepth: Option<Vec<f64>>,
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

impl ReferenceModel {
    /// Reads the model's weights through the engine's module tree (the same names, shapes and BatchNorm
    /// fold, in float64), into the reference's own float64 layers.
    pub fn new(model: &LoadedModel, argument: Argument) -> Result<ReferenceModel, EngineError> {
        let config = model.config.clone();
        let Family::Srt(srt_config) = &config.family else {
            return Err(EngineError::Request(format!("the float64 reference has no {} models", config.base())));
        };
        let (srt, weights) = nn::build(Source::File(model), |vars| Srt::new(vars, srt_config))?;
        let get = |p: Param| weights.get(p).data.to_f64();
        let dense = |l: &nn::Linear| Dense { w: get(l.weight), b: l.bias.map(get), n: l.out_dim, k: l.in_dim };
        let norm = |n: &nn::LayerNorm| Norm { gamma: get(n.gamma), beta: get(n.beta) };
        let conv = |c: &nn::Conv3x3| Conv { w: get(c.weight), b: c.bias.map(get), cin: c.cin, cout: c.cout };
        let layers = |t: &nn::Transformer| -> Vec<Layer> {
            t.layers
                .iter()
                .map(|l| Layer {
                    attn_norm: norm(&l.attn_norm),
                    projections: match &l.attn.projections {
                        Projections::SelfAttention { to_qkv } => vec![dense(to_qkv)],
                        Projections::Cross { to_q, to_kv } => vec![dense(to_q), dense(to_kv)],
                    },
                    to_out: dense(&l.attn.to_out),
                    ff_norm: norm(&l.ff_norm),
                    ff_in: dense(&l.ff.net_0),
                    ff_out: dense(&l.ff.net_3),
                })
                .collect()
        };
        let (e, d) = (&srt.encoder, &srt.decoder);
        let rp = &d.ray_predictor;
        Ok(ReferenceModel {
            argument,
            conv_blocks: e.conv_blocks.iter().map(|b| (conv(&b.conv_0), conv(&b.conv_3))).collect(),
            per_patch_linear: dense(&e.per_patch_linear),
            encoder_layers: layers(&e.transformer),
            input_mlp: (dense(&rp.input_mlp_0), dense(&rp.input_mlp_2)),
            decoder_layers: layers(&rp.transformer),
            out_mlp: d.out_mlp.iter().map(dense).collect(),
            ray_patch: srt
                .ray_patch
                .as_ref()
                .map(|rp| (conv(&rp.conv_0), rp.blocks.iter().map(|b| (conv(&b.features), conv(&b.to_rgb))).collect())),
            srt: srt_config.clone(),
            config,
        })
    }

    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    fn encoding(&self, coords: &[f64], repeat: usize, first_row: usize, rows: usize, octaves: &Octaves) -> Vec<f64> {
        let m = multipliers(octaves.count, octaves.start, octaves.end);
        fourier_encode_with(coords, repeat, first_row, rows, &m, self.argument)
    }

    /// `SRTEncoder`: the latent tokens of posed input views, and the decoder's keys and values.
    pub fn encode(&self, inputs: &InputViews) -> Result<ReferenceScene, ModelError> {
        inputs.check("input views")?;
        let e = &self.srt.encoder;
        let (n, h, w) = (inputs.count, inputs.height, inputs.width);
        let pixels = n * h * w;
        // [rgb, posenc(camera position), posenc(ray)] per pixel (NHWC), the position broadcast over its view.
        let pos = self.encoding(&f64s(&inputs.camera_pos), h * w, 0, pixels, &e.pos_octaves);
        let rays = self.encoding(&f64s(&inputs.rays), 1, 0, pixels, &e.ray_octaves);
        let (pos_w, ray_w) = (pos.len() / pixels, rays.len() / pixels);
        let mut x = Vec::with_capacity(pixels * (3 + pos_w + ray_w));
        for p in 0..pixels {
            x.extend(inputs.images[3 * p..3 * p + 3].iter().map(|&v| v as f64));
            x.extend_from_slice(&pos[p * pos_w..(p + 1) * pos_w]);
            x.extend_from_slice(&rays[p * ray_w..(p + 1) * ray_w]);
        }

        let (mut h, mut w) = (h, w);
        for (first, second) in &self.conv_blocks {
            let hidden = first.apply(&x, (n, h, w), 1, false, Activation::Relu, None);
            x = second.apply(&hidden, (n, h, w), 2, false, Activation::Relu, None);
            (h, w) = (h.div_ceil(2), w.div_ceil(2));
        }
        let tokens = n * h * w;
        let mut z = self.per_patch_linear.apply(&x, Activation::None, None);

        let inner = e.heads * e.dim_head;
        let scale = (e.dim_head as f64).powf(-0.5);
        for layer in &self.encoder_layers {
            let qkv = layer.projections[0].apply(&layer.attn_norm.apply(&z), Activation::None, None);
            let heads = parallel_rows(tokens, inner, |rows| {
                let q = &qkv[rows.start * 3 * inner..rows.end * 3 * inner];
                let (ld, (nq, nkv)) = (3 * inner, (rows.len(), tokens));
                attention(q, ld, 0, &qkv, ld, inner, &qkv, ld, 2 * inner, nq, nkv, e.heads, e.dim_head, scale)
            });
            z = layer.to_out.apply(&heads, Activation::None, Some(&z));
            z = feed_forward(&z, &layer.ff_norm, &layer.ff_in, &layer.ff_out);
        }
        let keys_values =
            self.decoder_layers.iter().map(|l| l.projections[1].apply(&z, Activation::None, None)).collect();
        Ok(ReferenceScene { latent: z, tokens, keys_values })
    }

    /// Renders target views of an encoded scene: `SRTDecoder` on every query (pixel, or patch for Ray-Patch),
    /// then the Ray-Patch decoder, then the sigmoid. Patch rays are made from full-resolution rays as the
    /// official loader makes them (bilinear), in f32 with [`Argument::RoundedToF32`] (PyTorch's float32
    /// operation order, which the engine reproduces bit for bit) and in f64 otherwise.
    pub fn render(&self, scene: &ReferenceScene, targets: &TargetViews) -> Result<ReferenceFrame, ModelError> {
        let cfg = &self.srt;
        let k = cfg.patch_size();
        let grid = targets.grid_for(&self.config, "target views")?;
        let (views, ph, pw) = (targets.count, grid.height / k, grid.width / k);
        let (rh, rw) = (targets.rays_height, targets.rays_width);
        let rays = if k > 1 && !grid.rays_are_patches {
            match self.argument {
                Argument::RoundedToF32 => f64s(&patch_rays_f32(&targets.rays, views, rh, rw, ph, pw)),
                Argument::Float64 => bilinear(&f64s(&targets.rays), views, rh, rw, 3, ph, pw),
            }
        } else {
            f64s(&targets.rays)
        };
        let queries = views * ph * pw;
        let positions = f64s(&targets.camera_pos);
        let mut features = Vec::with_capacity(queries * cfg.decoder.out_dims);
        for start in (0..queries).step_by(QUERY_CHUNK) {
            let rows = QUERY_CHUNK.min(queries - start);
            features.extend(self.decode(scene, &positions, ph * pw, start, &rays[3 * start..3 * (start + rows)]));
        }

        let channels = cfg.image_channels();
        let image = match &self.ray_patch {
            None => features,
            Some((conv_0, blocks)) => {
                // conv_0's output, bilinearly upsampled, is the first rgb skip; each block adds its rgb conv
                // to the skip, which is upsampled again for the next block.
                let (mut h, mut w) = (ph, pw);
                let first = conv_0.apply(&features, (views, h, w), 1, false, Activation::None, None);
                let mut skip = bilinear(&first, views, h, w, channels, 2 * h, 2 * w);
                let mut x = features;
                for (i, (feature_conv, to_rgb)) in blocks.iter().enumerate() {
                    x = leaky_relu(
                        feature_conv.apply(&x, (views, h, w), 1, true, Activation::None, None),
                        CONV_DECODER_SLOPE,
                    );
                    (h, w) = (2 * h, 2 * w);
                    skip = to_rgb.apply(&x, (views, h, w), 1, false, Activation::None, Some(&skip));
                    if i + 1 < blocks.len() {
                        skip = bilinear(&skip, views, h, w, channels, 2 * h, 2 * w);
                    }
                }
                skip
            }
        };
        // The official output resize (rp_kwargs h_out/w_out) when k does not divide the target size.
        let image = if (ph * k, pw * k) == (grid.height, grid.width) {
            image
        } else {
            nearest(&image, views, ph * k, pw * k, channels, grid.height, grid.width)
        };
        Ok(ReferenceFrame {
            views,
            height: grid.height,
            width: grid.width,
            rgb: map_columns(&image, channels, 0, 3, Map::Sigmoid),
            logdepth: (channels == 4).then(|| map_columns(&image, channels, 3, 1, Map::Identity)),
        })
    }

    /// `SRTDecoder` on query rows `[start, start + rays.len()/3)`: encodings, input_mlp, the cross-attention
    /// layers, out_mlp. Returns `[rows, out_dims]`.
    fn decode(
        &self,
        scene: &ReferenceScene,
        positions: &[f64],
        per_view: usize,
        start: usize,
        rays: &[f64],
    ) -> Vec<f64> {
        let d = &self.srt.decoder;
        let rows = rays.len() / 3;
        let pos = self.encoding(positions, per_view, start, rows, &d.pos_octaves);
        let ray = self.encoding(rays, 1, 0, rows, &d.ray_octaves);
        let (pos_w, ray_w) = (pos.len() / rows.max(1), ray.len() / rows.max(1));
        let mut query = Vec::with_capacity(rows * (pos_w + ray_w));
        for r in 0..rows {
            query.extend_from_slice(&pos[r * pos_w..(r + 1) * pos_w]);
            query.extend_from_slice(&ray[r * ray_w..(r + 1) * ray_w]);
        }
        let hidden = self.input_mlp.0.apply(&query, Activation::Relu, None);
        let mut x = self.input_mlp.1.apply(&hidden, Activation::None, None);

        let inner = d.heads * d.dim_head;
        let scale = (d.dim_head as f64).powf(-0.5);
        for (layer, kv) in self.decoder_layers.iter().zip(&scene.keys_values) {
            let q = layer.projections[0].apply(&layer.attn_norm.apply(&x), Activation::None, None);
            let heads = parallel_rows(rows, inner, |r| {
                let q = &q[r.start * inner..r.end * inner];
                let (ld, nkv) = (2 * inner, scene.tokens);
                attention(q, inner, 0, kv, ld, 0, kv, ld, inner, r.len(), nkv, d.heads, d.dim_head, scale)
            });
            x = layer.to_out.apply(&heads, Activation::None, Some(&x));
            x = feed_forward(&x, &layer.ff_norm, &layer.ff_in, &layer.ff_out);
        }
        let (last, hidden) = self.out_mlp.split_last().expect("out_mlp has five layers");
        for lin in hidden {
            x = leaky_relu(lin.apply(&x, Activation::None, None), OUT_MLP_SLOPE);
        }
        last.apply(&x, Activation::None, None)
    }
}

/// x + FF(LN(x)), FF = Linear → GELU → Linear.
fn feed_forward(x: &[f64], norm: &Norm, ff_in: &Dense, ff_out: &Dense) -> Vec<f64> {
    let hidden = ff_in.apply(&norm.apply(x), Activation::Gelu, None);
    ff_out.apply(&hidden, Activation::None, Some(x))
}

fn leaky_relu(mut x: Vec<f64>, slope: f64) -> Vec<f64> {
    x.iter_mut().filter(|v| **v < 0.0).for_each(|v| *v *= slope);
    x
}

/// PyTorch's float32 bilinear resize of NHWC rays `[n·hi·wi, 3]` to `[n·ho·wo, 3]`, in its channels-last
/// operation order `((x00·w00 + x01·w01) + x10·w10) + x11·w11` (weights multiplied first), as the engine's
/// patch rays compute it: with k a power of two the weights are exact and the result is PyTorch's, bit for bit.
fn patch_rays_f32(rays: &[f32], n: usize, hi: usize, wi: usize, ho: usize, wo: usize) -> Vec<f32> {
    let at = |b: usize, y: usize, x: usize, c: usize| rays[((b * hi + y) * wi + x) * 3 + c];
    let mut out = Vec::with_capacity(n * ho * wo * 3);
    for b in 0..n {
        for oy in 0..ho {
            let (y0, y1, ly) = linear_source(oy, hi, ho);
            let (h1, h0) = (ly as f32, 1.0 - ly as f32);
            for ox in 0..wo {
                let (x0, x1, lx) = linear_source(ox, wi, wo);
                let (w1, w0) = (lx as f32, 1.0 - lx as f32);
                for c in 0..3 {
                    let v = at(b, y0, x0, c) * (h0 * w0) + at(b, y0, x1, c) * (h0 * w1);
                    let v = v + at(b, y1, x0, c) * (h1 * w0);
                    out.push(v + at(b, y1, x1, c) * (h1 * w1));
                }
            }
        }
    }
    out
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
