//! SRT and RP-SRT (`base: srt`), as the official modules build them (tberriel/RayPatchQuerying
//! `src/encoder.py` `SRTEncoder`, `src/decoder.py` `SRTDecoder`/`RayPredictor`, `src/model.py` `SRT`):
//! posed images → conv blocks → tokens → transformer → latent z; ray queries → input MLP → cross-attention
//! to z → out MLP → per-ray colour (SRT) or patch features for the Ray-Patch decoder (RP-SRT).

use raypatch_model::{EncoderConfig, RayPredictorConfig, SrtConfig, TargetGrid};

use super::ray_patch::RayPatchDecoder;
use super::{image_output_set, image_outputs, in_query_chunks, target_queries, Encoded, LightField, QueryRows};
use crate::error::Result;
use crate::frame::{Output, Outputs};
use crate::graph::{Graph, HostInput, ImageSize, Tensor};
use crate::kernels::Activation;
use crate::nn::{Conv2d, ConvSpec, FourierEncoding, Linear, Transformer, TransformerDims, Vars};
use crate::tensor::GpuTensor;

/// LeakyReLU slope of the decoder's out_mlp (nn.LeakyReLU default).
pub const OUT_MLP_SLOPE: f32 = 0.01;

/// `SRTConvBlock`: conv(stride 1) → BN → ReLU → conv(stride 2) → BN → ReLU (`layers.0..5`), BN folded.
pub struct SrtConvBlock {
    pub conv_0: Conv2d,
    pub conv_3: Conv2d,
}

/// `SRTEncoder`.
pub struct SrtEncoder {
    pub pos_enc: FourierEncoding,
    pub ray_enc: FourierEncoding,
    pub conv_blocks: Vec<SrtConvBlock>,
    /// A 1×1 conv: conv features → tokens.
    pub per_patch_linear: Linear,
    pub transformer: Transformer,
    pub token_dim: usize,
}

/// `RayPredictor`: query encodings → input MLP → cross-attention layers (the SRT decoder's `ray_predictor`,
/// OSRT's `allocation_transformer`).
pub struct RayPredictor {
    pub pos_enc: FourierEncoding,
    pub ray_enc: FourierEncoding,
    pub input_mlp_0: Linear,
    pub input_mlp_2: Linear,
    pub transformer: Transformer,
}

/// `SRTDecoder` (`decoder_att`): the ray predictor, then the out MLP (four LeakyReLU layers and the output).
pub struct SrtDecoder {
    pub ray_predictor: RayPredictor,
    pub out_mlp: Vec<Linear>,
    /// The widest intermediate row of a query (sizes the query chunks).
    widest: usize,
}

/// SRT, or RP-SRT when `ray_patch` is set.
pub struct Srt {
    pub config: SrtConfig,
    pub encoder: SrtEncoder,
    pub decoder: SrtDecoder,
    pub ray_patch: Option<RayPatchDecoder>,
}

impl SrtConvBlock {
    fn new(vars: &Vars, cin: usize, hidden: usize, cout: usize, batch_norm: bool) -> Result<Self> {
        let layers = vars.pp("layers");
        let bn = |i: usize| batch_norm.then(|| layers.pp(i));
        Ok(SrtConvBlock {
            conv_0: Conv2d::new(&layers.pp(0), ConvSpec::new(cin, hidden, 3, 1, 1).no_bias(), bn(1))?,
            conv_3: Conv2d::new(&layers.pp(3), ConvSpec::new(hidden, cout, 3, 2, 1).no_bias(), bn(4))?,
        })
    }

    fn forward(&self, g: &mut Graph, x: Tensor) -> Tensor {
        let hidden = self.conv_0.forward(g, x, Activation::Relu);
        self.conv_3.forward(g, hidden, Activation::Relu)
    }
}

impl SrtEncoder {
    pub fn new(vars: &Vars, e: &EncoderConfig) -> Result<Self> {
        let mut conv_blocks = Vec::with_capacity(e.num_conv_blocks);
        let (mut cin, mut hidden) = (e.input_dim(), e.conv_hidden);
        for i in 0..e.num_conv_blocks {
            conv_blocks.push(SrtConvBlock::new(&vars.pp("conv_blocks").pp(i), cin, hidden, 2 * hidden, e.batch_norm)?);
            // The first block widens to 2·conv_hidden; each later block doubles its input.
            cin = 2 * hidden;
            hidden = cin;
        }
        let dims = TransformerDims {
            dim: e.token_dim,
            depth: e.num_att_blocks,
            heads: e.heads,
            dim_head: e.dim_head,
            mlp_dim: e.ff_hidden,
            kv_dim: None,
        };
        Ok(SrtEncoder {
            pos_enc: FourierEncoding::new(vars.pp("pos_enc").path(), &e.pos_octaves),
            ray_enc: FourierEncoding::new(vars.pp("ray_enc").path(), &e.ray_octaves),
            conv_blocks,
            per_patch_linear: Linear::conv1x1(&vars.pp("per_patch_linear"), cin, e.token_dim)?,
            transformer: Transformer::new(&vars.pp("transformer"), dims)?,
            token_dim: e.token_dim,
        })
    }

    /// The latent tokens z `[n·h'·w', token_dim]` of `size` posed input views, into the plan output `name`.
    pub fn forward(&self, g: &mut Graph, size: ImageSize, name: &str) -> Tensor {
        let (pos, ray) = (self.pos_enc.width(), self.ray_enc.width());
        // [rgb, posenc(camera position), posenc(ray)] per pixel: RGB written by the host, encodings by the
        // GPU; the position is broadcast over its view's pixels.
        let x = g.input(
            "encoder_input",
            size.pixels(),
            3 + pos + ray,
            HostInput::InputImages { col: 0, normalize: None },
            Some(size),
        );
        let camera_pos = g.input("input_camera_pos", size.n, 3, HostInput::InputCameraPos, None);
        let rays = g.input("input_rays", size.pixels(), 3, HostInput::InputRays, None);
        self.pos_enc.forward_into(g, camera_pos, size.h * size.w, 0, x, 3);
        self.ray_enc.forward_into(g, rays, 1, 0, x, 3 + pos);
        let x = self.conv_blocks.iter().fold(x, |x, block| block.forward(g, x));
        // per_patch_linear over NHWC rows gives the tokens in the official order: row-major per image,
        // images concatenated.
        let z = g.output(name, x.rows(), self.token_dim);
        self.per_patch_linear.forward_into(g, x, z, Activation::None, false);
        self.transformer.forward(g, z);
        z
    }
}

impl RayPredictor {
    /// The ray predictor at `vars`; its query encodings are labelled under `encodings`.
    pub fn new(vars: &Vars, encodings: &Vars, c: &RayPredictorConfig) -> Result<Self> {
        let q = c.query_dim();
        let transformer = TransformerDims {
            dim: q,
            depth: c.num_att_blocks,
            heads: c.heads,
            dim_head: c.dim_head,
            mlp_dim: c.ff_hidden,
            kv_dim: Some(c.kv_dim),
        };
        Ok(RayPredictor {
            pos_enc: FourierEncoding::new(encodings.pp("pos_enc").path(), &c.pos_octaves),
            ray_enc: FourierEncoding::new(encodings.pp("ray_enc").path(), &c.ray_octaves),
            input_mlp_0: Linear::new(&vars.pp("input_mlp.0"), q, c.input_mlp_hidden)?,
            input_mlp_2: Linear::new(&vars.pp("input_mlp.2"), c.input_mlp_hidden, q)?,
            transformer: Transformer::new(&vars.pp("transformer"), transformer)?,
        })
    }

    /// The widest intermediate row of a query inside the ray predictor (sizes the query chunks).
    pub fn widest(c: &RayPredictorConfig) -> usize {
        [c.ff_hidden, c.input_mlp_hidden, c.heads * c.dim_head, c.query_dim()].into_iter().max().unwrap_or(1)
    }

    /// The queries of `q` after the input MLP: input_mlp(cat(posenc(camera position), posenc(ray))).
    pub fn queries(&self, g: &mut Graph, q: QueryRows) -> Tensor {
        let pos = self.pos_enc.width();
        let query = g.transient("decoder_att.query", q.rows(), pos + self.ray_enc.width());
        self.pos_enc.forward_into(g, q.camera_pos, q.per_view, q.start, query, 0);
        self.ray_enc.forward_into(g, q.rays, 1, 0, query, pos);
        let hidden = self.input_mlp_0.forward(g, query, Activation::Relu);
        self.input_mlp_2.forward(g, hidden, Activation::None)
    }
}

impl SrtDecoder {
    fn new(vars: &Vars, c: &SrtConfig) -> Result<Self> {
        let d = &c.decoder;
        let q = c.query_dim();
        let h = d.out_mlp_hidden;
        let out_mlp = [(0, q, h), (2, h, h), (4, h, h), (6, h, h), (8, h, d.out_dims)]
            .into_iter()
            .map(|(i, inp, out)| Linear::new(&vars.pp("out_mlp").pp(i), inp, out))
            .collect::<Result<Vec<_>>>()?;
        Ok(SrtDecoder {
            ray_predictor: RayPredictor::new(&vars.pp("ray_predictor"), vars, &d.ray_predictor)?,
            out_mlp,
            widest: RayPredictor::widest(&d.ray_predictor).max(h),
        })
    }

    /// The decoder on query rows `q` into `out`: the ray predictor's queries, cross-attention, out MLP.
    fn forward(&self, g: &mut Graph, q: QueryRows, kv: &[Tensor], out: Tensor) {
        let rp = &self.ray_predictor;
        let x = rp.queries(g, q);
        rp.transformer.forward_cross(g, x, kv);
        let (last, hidden_layers) = self.out_mlp.split_last().expect("out_mlp has five layers");
        let h = hidden_layers.iter().fold(x, |h, lin| lin.forward(g, h, Activation::LeakyRelu(OUT_MLP_SLOPE)));
        last.forward_into(g, h, out, Activation::None, false);
    }
}

impl Srt {
    /// The module tree of `config` at `vars` (the model's root).
    pub fn new(vars: &Vars, config: &SrtConfig) -> Result<Srt> {
        Ok(Srt {
            encoder: SrtEncoder::new(&vars.pp("encoder"), &config.encoder)?,
            decoder: SrtDecoder::new(&vars.pp("decoder_att"), config)?,
            ray_patch: config
                .ray_patch
                .as_ref()
                .map(|rp| RayPatchDecoder::new(&vars.pp("decoder_rp.conv_decoder"), rp))
                .transpose()?,
            config: config.clone(),
        })
    }
}

impl LightField for Srt {
    fn outputs(&self) -> Outputs {
        image_output_set(self.config.image_channels())
    }

    fn patch_size(&self) -> usize {
        self.config.patch_size()
    }

    fn patch_span(&self, lo: usize, hi: usize, patches: usize) -> (usize, usize) {
        match &self.ray_patch {
            Some(rp) => rp.patch_span(lo, hi, patches),
            None => (lo, hi),
        }
    }

    fn encode(&self, g: &mut Graph, size: ImageSize) -> Encoded {
        let latent = self.encoder.forward(g, size, "latent");
        // The decoder's keys and values depend only on z: project them once per scene.
        let transformer = &self.decoder.ray_predictor.transformer;
        let keys_values: Vec<Tensor> = (0..transformer.layers.len())
            .map(|l| g.output(&format!("decoder.layers.{l}.kv"), latent.rows(), transformer.kv_width()))
            .collect();
        transformer.keys_values(g, latent, &keys_values);
        Encoded { latent, cached: keys_values }
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
        let kv: Vec<Tensor> =
            scene.iter().enumerate().map(|(l, t)| g.scene_tensor(&format!("decoder.layers.{l}.kv"), t)).collect();
        let features = g.image("decoder_features", patches, self.config.decoder.out_dims);
        in_query_chunks(g, patches.pixels(), self.decoder.widest, |g, start, rows| {
            self.decoder.forward(g, queries.slice(start, rows), &kv, features.slice(start, rows))
        });
        let image = match &self.ray_patch {
            Some(rp) => rp.forward(g, features, (grid.height, grid.width)),
            None => features,
        };
        image_outputs(g, image, outputs)
    }
}
