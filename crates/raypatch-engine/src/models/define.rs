//! DeFiNe and RP-DeFiNe (`base: define`), as the official modules build them (tberriel/RayPatchQuerying
//! `src/encoder.py` `DeFiNeEncoder`, `src/decoder.py` `DeFiNeDecoder`, `src/model.py` `DeFiNe`, on HuggingFace
//! transformers 4.24's Perceiver): posed images → ResNet-18 features at 1/4 size, concatenated with the ray
//! features → Perceiver IO encoder → 2048 latents; ray queries → one Perceiver cross-attention per head (rgb,
//! depth) → per-ray values (DeFiNe) or patch features for each head's Ray-Patch decoder (RP-DeFiNe).
//!
//! Rays are points at unit depth, not directions (the official ScanNet loader's `R·K⁻¹[u+0.5, v+0.5, 1] + t`).

use raypatch_model::config::define::{DEPTH_MAX, DEPTH_MIN};
use raypatch_model::{DefineConfig, RayFeatures, TargetGrid};

use super::ray_patch::RayPatchDecoder;
use super::{in_query_chunks, resized, target_queries, Encoded, LightField, QueryRows};
use crate::error::Result;
use crate::frame::{Output, Outputs};
use crate::graph::Param;
use crate::graph::{ChannelNorm, Graph, HostInput, ImageSize, Tensor};
use crate::kernels::copy::{copy_columns, CopyArgs};
use crate::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
use crate::kernels::resize::bilinear;
use crate::kernels::Activation;
use crate::nn::{FourierEncoding, KeysValues, Linear, PerceiverDims, PerceiverLayer, ResNet18, Vars};
use crate::tensor::GpuTensor;

/// The ImageNet normalisation the official ScanNet loader applies to input images (torchvision `Normalize`);
/// scene files hold RGB in [0, 1], so the engine applies it.
pub const IMAGENET: ChannelNorm = ChannelNorm { mean: [0.485, 0.456, 0.406], std: [0.229, 0.224, 0.225] };

/// The official `RayEncoder` with the raw values in front, as both `DeFiNeEncoder` and `DeFiNeDecoder`
/// concatenate them: `cat(ray, camera position, posenc(position), posenc(ray))`.
pub struct RayEncoder {
    pub pos_enc: FourierEncoding,
    pub ray_enc: FourierEncoding,
}

impl RayEncoder {
    fn new(path: &str, c: &RayFeatures) -> RayEncoder {
        RayEncoder {
            pos_enc: FourierEncoding::new(&format!("{path}.pos_encoding"), &c.pos_octaves),
            ray_enc: FourierEncoding::new(&format!("{path}.ray_encoding"), &c.ray_octaves),
        }
    }

    pub fn width(&self) -> usize {
        6 + self.pos_enc.width() + self.ray_enc.width()
    }

    /// The features of the query rows `q` into columns `col..col + width()` of `out`.
    fn forward_into(&self, g: &mut Graph, q: QueryRows, out: Tensor, col: usize) {
        let label = g.label(&format!("{}.rays", self.pos_enc.path));
        copy_columns(&mut g.b, &label, CopyArgs { x: q.rays.view, repeat: 1, first_row: 0, out: out.view, col });
        let label = g.label(&format!("{}.camera_pos", self.pos_enc.path));
        let args =
            CopyArgs { x: q.camera_pos.view, repeat: q.per_view, first_row: q.start, out: out.view, col: col + 3 };
        copy_columns(&mut g.b, &label, args);
        self.pos_enc.forward_into(g, q.camera_pos, q.per_view, q.start, out, col + 6);
        self.ray_enc.forward_into(g, q.rays, 1, 0, out, col + 6 + self.pos_enc.width());
    }
}

/// `DeFiNeEncoder`: `conv_blocks` (ResNet-18) and `transformer` (`PerceiverModel`: learned latents, one
/// cross-attention to the tokens, self-attention layers).
pub struct DefineEncoder {
    pub ray_encoder: RayEncoder,
    pub conv_blocks: ResNet18,
    /// `transformer.embeddings.latents` `[num_latents, latent_dim]`.
    pub latents: Param,
    pub cross_attention: PerceiverLayer,
    pub self_attends: Vec<PerceiverLayer>,
    pub num_latents: usize,
    pub latent_dim: usize,
    pub token_dim: usize,
}

impl DefineEncoder {
    fn new(vars: &Vars, c: &DefineConfig) -> Result<DefineEncoder> {
        let e = &c.encoder;
        let perceiver = vars.pp("transformer");
        let token_dim = e.token_dim();
        let cross = PerceiverDims { q_dim: e.latent_dim, kv_dim: Some(token_dim), heads: 1, query_residual: true };
        let self_attend = PerceiverDims { q_dim: e.latent_dim, kv_dim: None, heads: e.heads, query_residual: true };
        Ok(DefineEncoder {
            ray_encoder: RayEncoder::new(vars.pp("ray_encoder").path(), &e.rays),
            conv_blocks: ResNet18::new(&vars.pp("conv_blocks"), e.resnet_width)?,
            latents: perceiver.pp("embeddings").dense("latents", e.num_latents, e.latent_dim)?,
            cross_attention: PerceiverLayer::new(&perceiver.pp("encoder.cross_attention"), cross)?,
            self_attends: (0..e.num_att_blocks)
                .map(|l| PerceiverLayer::new(&perceiver.pp("encoder.self_attends").pp(l), self_attend))
                .collect::<Result<Vec<_>>>()?,
            num_latents: e.num_latents,
            latent_dim: e.latent_dim,
            token_dim,
        })
    }

    /// The latents `[num_latents, latent_dim]` of `size` posed input views, into the plan output `name`.
    pub fn forward(&self, g: &mut Graph, size: ImageSize, name: &str) -> Tensor {
        let images = g.input(
            "input_images",
            size.pixels(),
            3,
            HostInput::InputImages { col: 0, normalize: Some(IMAGENET) },
            Some(size),
        );
        let features = self.conv_blocks.forward(g, images);
        // Tokens per pixel of the first feature map: cat(x1, x2..x4 bilinearly resized to it, ray features).
        let grid = features[0].size();
        let tokens = g.image("encoder.tokens", grid, self.token_dim);
        let mut col = 0;
        for (i, &x) in features.iter().enumerate() {
            let x = if i == 0 { x } else { resized(g, &format!("encoder.x{}", i + 1), x, grid, bilinear) };
            let label = g.label(&format!("encoder.tokens.x{}", i + 1));
            copy_columns(&mut g.b, &label, CopyArgs { x: x.view, repeat: 1, first_row: 0, out: tokens.view, col });
            col += x.cols;
        }
        // The rays resized to H/4 × W/4 (the first feature map's size: `check_inputs` holds it to that).
        let camera_pos = g.input("input_camera_pos", size.n, 3, HostInput::InputCameraPos, None);
        let rays = g.input("input_rays", size.pixels(), 3, HostInput::InputRays, Some(size));
        let rays = resized(g, "encoder.rays", rays, grid, bilinear);
        let rays = QueryRows { camera_pos, per_view: grid.h * grid.w, start: 0, rays };
        self.ray_encoder.forward_into(g, rays, tokens, col);

        // The Perceiver: the learned latents cross-attend to the tokens (latent rows independently, so in
        // chunks that bound the scores), then attend to themselves.
        let latent = g.output(name, self.num_latents, self.latent_dim);
        let label = g.label("encoder.transformer.embeddings.latents");
        let latents = g.param(&label, self.latents);
        let args = MapColumnsArgs { x: g.b.all(latents), col: 0, out: latent.view, map: Map::Identity };
        map_columns(&mut g.b, &label, args);
        let (inner, (rows, cols)) =
            (self.cross_attention.dims.inner(), self.cross_attention.values_shape(tokens.rows()));
        let kv = KeysValues {
            keys: g.transient("encoder.cross_attention.keys", tokens.rows(), inner),
            values: g.transient("encoder.cross_attention.values", rows, cols),
        };
        self.cross_attention.keys_values(g, tokens, kv);
        let widest = self.cross_attention.widest().max(tokens.rows());
        in_query_chunks(g, self.num_latents, widest, |g, start, rows| {
            self.cross_attention.forward(g, latent.slice(start, rows), Some(kv));
        });
        for layer in &self.self_attends {
            layer.forward(g, latent, None);
        }
        latent
    }
}

/// `DeFiNeDecoder` (`decoder_att_rgb`, `decoder_att_d`): the query features, the `PerceiverBasicDecoder`'s
/// cross-attention to the latents (no query residual) and its `final_layer`.
pub struct DefineDecoder {
    pub query_encoder: RayEncoder,
    pub cross_attention: PerceiverLayer,
    pub final_layer: Linear,
}

impl DefineDecoder {
    fn new(vars: &Vars, c: &DefineConfig, out_dims: usize) -> Result<DefineDecoder> {
        let d = &c.decoder;
        let q_dim = d.rays.width();
        let dims = PerceiverDims { q_dim, kv_dim: Some(d.latent_dim), heads: 1, query_residual: false };
        let transformer = vars.pp("transformer");
        Ok(DefineDecoder {
            query_encoder: RayEncoder::new(vars.pp("query_encoder").path(), &d.rays),
            cross_attention: PerceiverLayer::new(&transformer.pp("decoding_cross_attention"), dims)?,
            final_layer: Linear::new(&transformer.pp("final_layer"), q_dim, out_dims)?,
        })
    }

    /// The widest row of a query (the scores over the latents, when they are materialised).
    fn widest(&self, num_latents: usize) -> usize {
        let layer = &self.cross_attention;
        let scores = if layer.materialises_scores() { num_latents } else { 0 };
        layer.widest().max(scores).max(self.query_encoder.width())
    }

    /// The decoder on query rows `q` into `out`.
    fn forward(&self, g: &mut Graph, q: QueryRows, kv: KeysValues, out: Tensor) {
        let path = format!("{}.query", self.cross_attention.path);
        let queries = g.transient(&path, q.rows(), self.query_encoder.width());
        self.query_encoder.forward_into(g, q, queries, 0);
        let h = self.cross_attention.forward(g, queries, Some(kv));
        self.final_layer.forward_into(g, h, out, Activation::None, false);
    }
}

/// One output head: its attention decoder, its Ray-Patch decoder (RP-DeFiNe), and the outputs it gives.
pub struct Head {
    pub name: &'static str,
    pub decoder: DefineDecoder,
    pub ray_patch: Option<RayPatchDecoder>,
    /// Each output of the head with the map from the pre-activation image.
    pub outputs: Vec<(Output, Map)>,
}

/// DeFiNe, or RP-DeFiNe when the heads have Ray-Patch decoders.
pub struct Define {
    pub config: DefineConfig,
    pub encoder: DefineEncoder,
    /// rgb, then depth.
    pub heads: [Head; 2],
}

impl Define {
    /// The module tree of `config` at `vars` (the model's root).
    pub fn new(vars: &Vars, config: &DefineConfig) -> Result<Define> {
        let (rgb_dims, depth_dims) = config.head_dims();
        let head = |name: &'static str, suffix: &str, dims: usize, image_channels: usize, outputs| -> Result<Head> {
            let ray_patch = match &config.ray_patch {
                Some(rp) => {
                    let rp = raypatch_model::RayPatchConfig { out_dims: image_channels, ..rp.clone() };
                    Some(RayPatchDecoder::new(&vars.pp(format!("decoder_rp_{suffix}.conv_decoder")), &rp)?)
                }
                None => None,
            };
            let decoder = DefineDecoder::new(&vars.pp(format!("decoder_att_{suffix}")), config, dims)?;
            Ok(Head { name, decoder, ray_patch, outputs })
        };
        // The official depth: log(sigmoid(x)·(d_max − d_min) + d_min), in float32.
        let (scale, offset) = (DEPTH_MAX - DEPTH_MIN, DEPTH_MIN);
        let encoder = DefineEncoder::new(&vars.pp("encoder"), config)?;
        let rgb = head("rgb", "rgb", rgb_dims, 3, vec![(Output::Rgb, Map::Sigmoid)])?;
        let depth_outputs = vec![
            (Output::LogDepth, Map::LogSigmoidAffine { scale, offset }),
            (Output::Depth, Map::SigmoidAffine { scale, offset }),
        ];
        let depth = head("depth", "d", depth_dims, 1, depth_outputs)?;
        Ok(Define { config: config.clone(), encoder, heads: [rgb, depth] })
    }
}

impl LightField for Define {
    fn outputs(&self) -> Outputs {
        Outputs::of(&[Output::Rgb, Output::LogDepth, Output::Depth])
    }

    fn patch_size(&self) -> usize {
        self.config.patch_size()
    }

    fn patch_span(&self, lo: usize, hi: usize, patches: usize) -> (usize, usize) {
        // Both heads' Ray-Patch decoders have the same structure.
        match &self.heads[0].ray_patch {
            Some(rp) => rp.patch_span(lo, hi, patches),
            None => (lo, hi),
        }
    }

    fn check_inputs(&self, height: usize, width: usize) -> std::result::Result<(), String> {
        // The official encoder concatenates the ResNet's first feature map (⌈⌈s/2⌉/2⌉ a side) with the rays
        // resized to ⌊s/4⌋: they agree only for sides divisible by 4.
        if !height.is_multiple_of(4) || !width.is_multiple_of(4) {
            return Err(format!(
                "input views of {width}x{height}: DeFiNe needs input sizes divisible by 4 (its encoder joins the ResNet features at 1/4 size with the rays resized to H/4 x W/4)"
            ));
        }
        Ok(())
    }

    fn encode(&self, g: &mut Graph, size: ImageSize) -> Encoded {
        let latent = self.encoder.forward(g, size, "latent");
        // Each head's keys and values depend only on the latents: project them once per scene.
        let mut cached = Vec::new();
        for head in &self.heads {
            let layer = &head.decoder.cross_attention;
            let (inner, (rows, cols)) = (layer.dims.inner(), layer.values_shape(latent.rows()));
            let kv = KeysValues {
                keys: g.output(&format!("decoder_{}.keys", head.name), latent.rows(), inner),
                values: g.output(&format!("decoder_{}.values", head.name), rows, cols),
            };
            layer.keys_values(g, latent, kv);
            cached.extend([kv.keys, kv.values]);
        }
        Encoded { latent, cached }
    }

    fn render(
        &self,
        g: &mut Graph,
        scene: &[GpuTensor],
        views: usize,
        grid: TargetGrid,
        outputs: Outputs,
    ) -> Vec<(Output, Tensor)> {
        let k = self.patch_size();
        let (queries, patches) = target_queries(g, self.heads[0].ray_patch.as_ref(), k, views, grid);
        let mut rendered = Vec::new();
        for (h, head) in self.heads.iter().enumerate() {
            // A head runs only for the outputs it gives that were asked for.
            if !head.outputs.iter().any(|&(o, _)| outputs.contains(o)) {
                continue;
            }
            let kv = KeysValues {
                keys: g.scene_tensor(&format!("decoder_{}.keys", head.name), &scene[2 * h]),
                values: g.scene_tensor(&format!("decoder_{}.values", head.name), &scene[2 * h + 1]),
            };
            let dims = head.decoder.final_layer.out_dim;
            let features = g.image(&format!("decoder_{}.features", head.name), patches, dims);
            let widest = head.decoder.widest(self.encoder.num_latents);
            in_query_chunks(g, patches.pixels(), widest, |g, start, rows| {
                head.decoder.forward(g, queries.slice(start, rows), kv, features.slice(start, rows))
            });
            let image = match &head.ray_patch {
                Some(rp) => rp.forward(g, features, (grid.height, grid.width)),
                None => features,
            };
            for &(output, map) in &head.outputs {
                if outputs.contains(output) {
                    let t = g.output(output.name(), image.rows(), image.cols);
                    let label = g.label(output.name());
                    map_columns(&mut g.b, &label, MapColumnsArgs { x: image.view, col: 0, out: t.view, map });
                    rendered.push((output, t));
                }
            }
        }
        rendered
    }
}
