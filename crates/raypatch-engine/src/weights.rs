//! The model's weights on the GPU, in the layouts the kernels read, under the official module structure:
//! `SrtWeights.encoder.layers[l].to_qkv` is `encoder.transformer.layers.{l}.0.fn.to_qkv`, and so on.
//! BatchNorm (eval mode) is folded into the preceding convolution here, once, at load time.

use raypatch_model::{LoadedModel, ModelConfig};

use crate::error::{EngineError, Result};
use crate::gpu::Gpu;
use crate::kernels::conv::pack_conv3x3;
use crate::tensor::GpuTensor;

/// PyTorch's BatchNorm2d default.
const BATCH_NORM_EPS: f64 = 1e-5;

/// How the linear layers' weights are stored on the GPU (they are most of the bytes and of the time).
/// Everything else (convolutions, biases, norms, activations) stays f32, and all arithmetic is f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum WeightStorage {
    #[default]
    F32,
    /// f16 (needs the adapter's `SHADER_F16`). A layer with a weight beyond f16's range (|w| > 65504,
    /// which f16 would turn into infinity) stays f32 and is listed in [`SrtWeights::kept_f32`].
    F16,
}

/// Options for putting a model on the GPU.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    pub weight_storage: WeightStorage,
}

/// A linear layer that stays f32 under [`WeightStorage::F16`], and why.
#[derive(Clone, Debug, PartialEq)]
pub struct KeptF32 {
    pub tensor: String,
    /// The largest |weight|, beyond f16's range.
    pub max_abs: f32,
}

/// nn.Linear: weight [out, in], optional bias stored as a [1, out] row.
pub struct Linear {
    pub weight: GpuTensor,
    pub bias: Option<GpuTensor>,
}

/// nn.LayerNorm affine terms as [1, C] rows.
pub struct LayerNorm {
    pub gamma: GpuTensor,
    pub beta: GpuTensor,
}

/// A 3×3 convolution (BatchNorm folded in), packed by [`pack_conv3x3`].
pub struct Conv3x3 {
    pub weight: GpuTensor,
    pub bias: Option<GpuTensor>,
    pub cin: usize,
    pub cout: usize,
}

/// One pre-norm transformer layer: attention then feed-forward, each with its LayerNorm.
pub struct EncoderLayer {
    pub attn_norm: LayerNorm,
    pub to_qkv: Linear,
    pub to_out: Linear,
    pub ff_norm: LayerNorm,
    pub ff_in: Linear,
    pub ff_out: Linear,
}

/// One decoder layer: cross-attention from the ray queries to the latent tokens, then feed-forward.
pub struct DecoderLayer {
    pub attn_norm: LayerNorm,
    pub to_q: Linear,
    /// Applied to the latent tokens once per scene (see `EncodedScene`), never per render.
    pub to_kv: Linear,
    pub to_out: Linear,
    pub ff_norm: LayerNorm,
    pub ff_in: Linear,
    pub ff_out: Linear,
}

pub struct EncoderWeights {
    /// Per SRTConvBlock: the stride-1 conv and the stride-2 conv.
    pub conv_blocks: Vec<(Conv3x3, Conv3x3)>,
    pub per_patch_linear: Linear,
    pub layers: Vec<EncoderLayer>,
}

pub struct DecoderWeights {
    pub input_mlp: (Linear, Linear),
    pub layers: Vec<DecoderLayer>,
    /// Five linears: four LeakyReLU(0.01) hidden layers and the output layer.
    pub out_mlp: Vec<Linear>,
}

/// The Ray-Patch conv decoder (`decoder_rp.conv_decoder`).
pub struct RayPatchWeights {
    /// `conv_0`: the first RGB skip, from the patch features.
    pub conv_0: Conv3x3,
    /// Per upsampling block: the feature conv (on the 2× nearest-upsampled input) and its RGB output conv.
    pub blocks: Vec<(Conv3x3, Conv3x3)>,
}

pub struct SrtWeights {
    pub encoder: EncoderWeights,
    pub decoder: DecoderWeights,
    pub ray_patch: Option<RayPatchWeights>,
    /// Bytes of GPU memory the weights take.
    pub bytes: u64,
    /// Linear layers kept in f32 under [`WeightStorage::F16`] because a weight is beyond f16's range.
    pub kept_f32: Vec<KeptF32>,
}

struct Uploader<'a> {
    gpu: &'a Gpu,
    model: &'a LoadedModel,
    storage: WeightStorage,
    bytes: u64,
    kept_f32: Vec<KeptF32>,
}

impl Uploader<'_> {
    fn tensor(&mut self, label: &str, rows: usize, cols: usize, data: &[f32]) -> Result<GpuTensor> {
        let t = self.gpu.upload(label, rows, cols, data)?;
        self.bytes += t.bytes();
        Ok(t)
    }

    fn row(&mut self, key: &str) -> Result<GpuTensor> {
        let w = self.model.weight(key);
        self.tensor(key, 1, w.data.len(), &w.data)
    }

    fn linear(&mut self, prefix: &str, bias: bool) -> Result<Linear> {
        let key = format!("{prefix}.weight");
        let w = self.model.weight(&key);
        // Linear weights are [out, in]; the 1×1 per_patch_linear conv is [out, in, 1, 1].
        let (rows, cols) = (w.shape[0], w.data.len() / w.shape[0]);
        let max_abs = w.data.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let weight = match self.storage {
            WeightStorage::F16 if half::f16::from_f32(max_abs).is_finite() => {
                let t = self.gpu.upload_f16(&key, rows, cols, &w.data)?;
                self.bytes += t.bytes();
                t
            }
            WeightStorage::F16 => {
                self.kept_f32.push(KeptF32 { tensor: key.clone(), max_abs });
                self.tensor(&key, rows, cols, &w.data)?
            }
            WeightStorage::F32 => self.tensor(&key, rows, cols, &w.data)?,
        };
        let bias = if bias { Some(self.row(&format!("{prefix}.bias"))?) } else { None };
        Ok(Linear { weight, bias })
    }

    fn layer_norm(&mut self, prefix: &str) -> Result<LayerNorm> {
        Ok(LayerNorm { gamma: self.row(&format!("{prefix}.weight"))?, beta: self.row(&format!("{prefix}.bias"))? })
    }

    /// A conv `weight_key` [cout, cin, 3, 3] with optional bias, folding in the eval-mode BatchNorm at
    /// `batch_norm` when given: w' = w·γ/√(σ²+ε), b' = β + (b − μ)·γ/√(σ²+ε).
    fn conv(&mut self, weight_key: &str, bias_key: Option<&str>, batch_norm: Option<&str>) -> Result<Conv3x3> {
        let w = self.model.weight(weight_key);
        let (cout, cin) = (w.shape[0], w.shape[1]);
        let mut weight: Vec<f32> = w.data.clone();
        let mut bias: Option<Vec<f64>> =
            bias_key.map(|k| self.model.weight(k).data.iter().map(|&v| v as f64).collect());
        if let Some(bn) = batch_norm {
            let get = |name: &str| &self.model.weight(&format!("{bn}.{name}")).data;
            let (gamma, beta, mean, var) = (get("weight"), get("bias"), get("running_mean"), get("running_var"));
            let mut folded = Vec::with_capacity(cout);
            for c in 0..cout {
                let scale = gamma[c] as f64 / (var[c] as f64 + BATCH_NORM_EPS).sqrt();
                for v in &mut weight[c * cin * 9..(c + 1) * cin * 9] {
                    *v = (*v as f64 * scale) as f32;
                }
                let b = bias.as_ref().map_or(0.0, |b| b[c]);
                folded.push(beta[c] as f64 + (b - mean[c] as f64) * scale);
            }
            bias = Some(folded);
        }
        let packed = pack_conv3x3(&weight, cout, cin);
        let weight = self.tensor(weight_key, cout, packed.len() / cout, &packed)?;
        let bias = match bias {
            Some(b) => Some(self.tensor(
                bias_key.unwrap_or(weight_key),
                1,
                cout,
                &b.iter().map(|&v| v as f32).collect::<Vec<_>>(),
            )?),
            None => None,
        };
        Ok(Conv3x3 { weight, bias, cin, cout })
    }
}

impl SrtWeights {
    pub fn upload(gpu: &Gpu, model: &LoadedModel, options: &LoadOptions) -> Result<SrtWeights> {
        let config: &ModelConfig = &model.config;
        if options.weight_storage == WeightStorage::F16 && !gpu.features.contains(wgpu::Features::SHADER_F16) {
            return Err(EngineError::Request(format!(
                "f16 weights need shader-f16, which {} does not have",
                gpu.info.name
            )));
        }
        let mut up = Uploader { gpu, model, storage: options.weight_storage, bytes: 0, kept_f32: Vec::new() };
        let bn = |on: bool, key: String| on.then_some(key);

        let e = &config.encoder;
        let mut conv_blocks = Vec::with_capacity(e.num_conv_blocks);
        for i in 0..e.num_conv_blocks {
            let p = format!("encoder.conv_blocks.{i}.layers");
            let first = up.conv(&format!("{p}.0.weight"), None, bn(e.batch_norm, format!("{p}.1")).as_deref())?;
            let second = up.conv(&format!("{p}.3.weight"), None, bn(e.batch_norm, format!("{p}.4")).as_deref())?;
            conv_blocks.push((first, second));
        }
        let per_patch_linear = up.linear("encoder.per_patch_linear", true)?;
        let mut layers = Vec::with_capacity(e.num_att_blocks);
        for l in 0..e.num_att_blocks {
            let p = format!("encoder.transformer.layers.{l}");
            layers.push(EncoderLayer {
                attn_norm: up.layer_norm(&format!("{p}.0.norm"))?,
                to_qkv: up.linear(&format!("{p}.0.fn.to_qkv"), false)?,
                to_out: up.linear(&format!("{p}.0.fn.to_out.1"), true)?,
                ff_norm: up.layer_norm(&format!("{p}.1.norm"))?,
                ff_in: up.linear(&format!("{p}.1.fn.net.0"), true)?,
                ff_out: up.linear(&format!("{p}.1.fn.net.3"), true)?,
            });
        }
        let encoder = EncoderWeights { conv_blocks, per_patch_linear, layers };

        let rp = "decoder_att.ray_predictor";
        let input_mlp =
            (up.linear(&format!("{rp}.input_mlp.0"), true)?, up.linear(&format!("{rp}.input_mlp.2"), true)?);
        let mut layers = Vec::with_capacity(config.decoder.num_att_blocks);
        for l in 0..config.decoder.num_att_blocks {
            let p = format!("{rp}.transformer.layers.{l}");
            layers.push(DecoderLayer {
                attn_norm: up.layer_norm(&format!("{p}.0.norm"))?,
                to_q: up.linear(&format!("{p}.0.fn.to_q"), false)?,
                to_kv: up.linear(&format!("{p}.0.fn.to_kv"), false)?,
                to_out: up.linear(&format!("{p}.0.fn.to_out.1"), true)?,
                ff_norm: up.layer_norm(&format!("{p}.1.norm"))?,
                ff_in: up.linear(&format!("{p}.1.fn.net.0"), true)?,
                ff_out: up.linear(&format!("{p}.1.fn.net.3"), true)?,
            });
        }
        let out_mlp = [0, 2, 4, 6, 8]
            .iter()
            .map(|i| up.linear(&format!("decoder_att.out_mlp.{i}"), true))
            .collect::<Result<Vec<_>>>()?;
        let decoder = DecoderWeights { input_mlp, layers, out_mlp };

        let ray_patch = match &config.ray_patch {
            None => None,
            Some(cfg) => {
                let p = "decoder_rp.conv_decoder";
                let conv_0 = up.conv(&format!("{p}.conv_0.weight"), Some(&format!("{p}.conv_0.bias")), None)?;
                let mut blocks = Vec::with_capacity(cfg.upsample);
                for i in 0..cfg.upsample {
                    let b = format!("{p}.conv_blocks.{i}");
                    let feature = up.conv(
                        &format!("{b}.0.1.weight"),
                        Some(&format!("{b}.0.1.bias")),
                        bn(cfg.batch_norm, format!("{b}.0.2")).as_deref(),
                    )?;
                    let to_rgb = up.conv(&format!("{b}.1.weight"), Some(&format!("{b}.1.bias")), None)?;
                    blocks.push((feature, to_rgb));
                }
                Some(RayPatchWeights { conv_0, blocks })
            }
        };
        Ok(SrtWeights { encoder, decoder, ray_patch, bytes: up.bytes, kept_f32: up.kept_f32 })
    }
}
