//! SRT in float64 (`models/srt.rs`): the `SRTEncoder` (shared by OSRT), the `RayPredictor` (the SRT decoder's
//! ray predictor, OSRT's allocation transformer) and the `SRTDecoder`.

use raypatch_model::InputViews;

use super::{f64s, leaky_relu, Conv, Dense, Layer, QueryRows, RayEncoder, Reader, ReferenceScene, OUT_MLP_SLOPE};
use crate::concat::concat_columns;
use raypatch_engine::kernels::Activation;
use raypatch_engine::models::srt::{
    RayPredictor as EngineRayPredictor, SrtDecoder as EngineSrtDecoder, SrtEncoder as EngineSrtEncoder,
};

/// `SRTEncoder`: conv blocks, per-patch linear, self-attention transformer.
pub(super) struct SrtEncoder {
    ray_encoder: RayEncoder,
    conv_blocks: Vec<(Conv, Conv)>,
    per_patch_linear: Dense,
    layers: Vec<Layer>,
}

/// `RayPredictor`: query encodings → input MLP → cross-attention layers to the latent.
pub(super) struct RayPredictor {
    query_encoder: RayEncoder,
    input_mlp: (Dense, Dense),
    layers: Vec<Layer>,
}

/// `SRTDecoder`: the ray predictor, then the out MLP (four LeakyReLU layers and the output).
pub(super) struct SrtDecoder {
    ray_predictor: RayPredictor,
    out_mlp: Vec<Dense>,
}

impl SrtEncoder {
    pub(super) fn read(r: &Reader, e: &EngineSrtEncoder) -> SrtEncoder {
        SrtEncoder {
            ray_encoder: r.ray_encoder(&e.pos_enc, &e.ray_enc, false),
            conv_blocks: e.conv_blocks.iter().map(|b| (r.conv(&b.conv_0), r.conv(&b.conv_3))).collect(),
            per_patch_linear: r.dense(&e.per_patch_linear),
            layers: r.layers(&e.transformer),
        }
    }

    pub(super) fn token_dim(&self) -> usize {
        self.per_patch_linear.n
    }

    /// The latent tokens `[n·h'·w', token_dim]` of (checked) posed input views.
    pub(super) fn forward(&self, inputs: &InputViews) -> Vec<f64> {
        let (n, h, w) = (inputs.count, inputs.height, inputs.width);
        // [rgb, posenc(camera position), posenc(ray)] per pixel (NHWC), the position broadcast over its view.
        let (positions, rays) = (f64s(&inputs.camera_pos), f64s(&inputs.rays));
        let pixels = QueryRows { positions: &positions, per_view: h * w, start: 0, rays: &rays };
        let encoded = self.ray_encoder.forward(&pixels);
        let mut x = concat_columns(&f64s(&inputs.images), 3, &encoded, self.ray_encoder.width());

        let (mut h, mut w) = (h, w);
        for (first, second) in &self.conv_blocks {
            let hidden = first.apply(&x, (n, h, w), 1, false, Activation::Relu, None);
            x = second.apply(&hidden, (n, h, w), 2, false, Activation::Relu, None);
            (h, w) = (h.div_ceil(2), w.div_ceil(2));
        }
        let z = self.per_patch_linear.forward(&x);
        self.layers.iter().fold(z, |z, layer| layer.self_attend(&z))
    }
}

impl RayPredictor {
    pub(super) fn read(r: &Reader, p: &EngineRayPredictor) -> RayPredictor {
        RayPredictor {
            query_encoder: r.ray_encoder(&p.pos_enc, &p.ray_enc, false),
            input_mlp: (r.dense(&p.input_mlp_0), r.dense(&p.input_mlp_2)),
            layers: r.layers(&p.transformer),
        }
    }

    /// Per cross-attention layer, `to_kv(latent)`: computed once per scene.
    pub(super) fn keys_values(&self, latent: &[f64]) -> Vec<Vec<f64>> {
        self.layers.iter().map(|l| l.keys_values(latent)).collect()
    }

    /// The queries after the input MLP, `[rows, query_dim]`: input_mlp(cat(posenc(camera position),
    /// posenc(ray))).
    pub(super) fn queries(&self, q: &QueryRows) -> Vec<f64> {
        let hidden = self.input_mlp.0.apply(&self.query_encoder.forward(q), Activation::Relu, None);
        self.input_mlp.1.forward(&hidden)
    }

    /// The cross-attention layers on queries `x`, reading the scene's keys and values.
    pub(super) fn attend(&self, x: Vec<f64>, scene: &ReferenceScene) -> Vec<f64> {
        self.layers.iter().zip(&scene.keys_values).fold(x, |x, (layer, kv)| layer.cross_attend(&x, kv))
    }
}

impl SrtDecoder {
    pub(super) fn read(r: &Reader, d: &EngineSrtDecoder) -> SrtDecoder {
        SrtDecoder {
            ray_predictor: RayPredictor::read(r, &d.ray_predictor),
            out_mlp: d.out_mlp.iter().map(|l| r.dense(l)).collect(),
        }
    }

    /// The encoded scene of the latent tokens `[tokens, token_dim]`.
    pub(super) fn scene(&self, latent: Vec<f64>, tokens: usize) -> ReferenceScene {
        ReferenceScene {
            keys_values: self.ray_predictor.keys_values(&latent),
            latent,
            tokens,
            set_latent: None,
            mixing_keys: None,
        }
    }

    /// `SRTDecoder` on query rows: the ray predictor, the out MLP. Returns `[rows, out_dims]`.
    pub(super) fn decode(&self, scene: &ReferenceScene, q: &QueryRows) -> Vec<f64> {
        let rp = &self.ray_predictor;
        let x = rp.attend(rp.queries(q), scene);
        let (last, hidden) = self.out_mlp.split_last().expect("out_mlp has five layers");
        let x = hidden.iter().fold(x, |x, lin| leaky_relu(lin.forward(&x), OUT_MLP_SLOPE));
        last.forward(&x)
    }
}
