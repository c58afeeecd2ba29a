//! `base: define`: the config of DeFiNe (`decoder: lightfield`) and RP-DeFiNe (`decoder: featurefield`), as the
//! official `DeFiNe` model class reads it (tberriel/RayPatchQuerying `src/model.py`; `DeFiNeEncoder` in
//! `src/encoder.py`, `DeFiNeDecoder` in `src/decoder.py`, the ResNet-18 of `src/resnet.py`, HuggingFace
//! transformers 4.24 `PerceiverModel` / `PerceiverBasicDecoder`).
//!
//! The official modules hard-code the ResNet-18 widths (64..512), the Perceiver latent width (512) and its
//! self-attention heads (8); raypatch extension keys name them so that small models can be built, defaulting
//! to the official values (docs/FORMATS.md).

use serde_json::Value;

use super::{
    check_octaves, check_positive, check_widths, config_err, Count, FamilyConfig, Octaves, RayKind, RayPatchConfig,
    Section,
};
use crate::error::{ModelError, Quoted};

/// The official depth range: logdepth = log(sigmoid(x)·(d_max − d_min) + d_min).
pub const DEPTH_MIN: f32 = 0.1;
pub const DEPTH_MAX: f32 = 10.0;

/// Width of the ray features beside the Fourier encodings: the ray (3) and the camera position (3).
pub const RAW_RAY_FEATURES: usize = 6;

/// The ray features of `DeFiNeEncoder` and `DeFiNeDecoder`: cat(ray, camera position, posenc(position),
/// posenc(ray)), both encodings linspace octaves.
#[derive(Clone, Debug, PartialEq)]
pub struct RayFeatures {
    pub pos_octaves: Octaves,
    pub ray_octaves: Octaves,
}

impl RayFeatures {
    /// The official `DeFiNeEncoder`/`DeFiNeDecoder` defaults: 20 position and 10 ray octaves, linspace 1..30.
    fn from_section(s: &Section) -> Result<Self, ModelError> {
        let linspace = |name: &str, count: usize| -> Result<Octaves, ModelError> {
            Ok(Octaves {
                count: s.usize(&format!("{name}_octaves"), count, Count::Octaves)?,
                start: s.f64(&format!("{name}_start_octave"), 1.0)?,
                end: Some(s.f64(&format!("{name}_end_octave"), 30.0)?),
            })
        };
        Ok(RayFeatures { pos_octaves: linspace("pos", 20)?, ray_octaves: linspace("ray", 10)? })
    }

    /// Columns: 6 + 6·(position octaves + ray octaves) (186 officially).
    pub fn width(&self) -> usize {
        RAW_RAY_FEATURES + 6 * (self.pos_octaves.count + self.ray_octaves.count)
    }
}

/// `DeFiNeEncoder`: ResNet-18 features and ray features → 1146-wide tokens → Perceiver IO encoder.
#[derive(Clone, Debug, PartialEq)]
pub struct DefineEncoderConfig {
    pub rays: RayFeatures,
    /// ResNet-18's stem and layer1 width; layer2..4 are 2×, 4×, 8× (official 64, raypatch `resnet_width`).
    pub resnet_width: usize,
    /// Perceiver latents (`num_latents`, official 2048).
    pub num_latents: usize,
    /// Perceiver latent width (`d_latents`, official 512, raypatch `latent_dim`).
    pub latent_dim: usize,
    /// Self-attention layers (`num_att_blocks` → `num_self_attends_per_block`, official 8).
    pub num_att_blocks: usize,
    /// Self-attention heads (official 8, raypatch `heads`); the cross-attention has one head.
    pub heads: usize,
}

impl DefineEncoderConfig {
    /// The four ResNet feature widths: w, 2w, 4w, 8w.
    pub fn resnet_widths(&self) -> [usize; 4] {
        let w = self.resnet_width;
        [w, 2 * w, 4 * w, 8 * w]
    }

    /// Token width: the four feature maps and the ray features (official 960 + 186 = 1146).
    pub fn token_dim(&self) -> usize {
        15 * self.resnet_width + self.rays.width()
    }
}

/// `DeFiNeDecoder` (one for rgb, one for depth): a `PerceiverBasicDecoder` with one single-head
/// cross-attention from the ray features to the latents, no query residual, and a final linear layer.
#[derive(Clone, Debug, PartialEq)]
pub struct DefineDecoderConfig {
    pub rays: RayFeatures,
    /// The latents' width (official `latent_dim` 512; must equal the encoder's).
    pub latent_dim: usize,
}

/// DeFiNe and RP-DeFiNe.
#[derive(Clone, Debug, PartialEq)]
pub struct DefineConfig {
    pub encoder: DefineEncoderConfig,
    pub decoder: DefineDecoderConfig,
    /// Present for `decoder: featurefield` (RP-DeFiNe): the rgb head's Ray-Patch decoder (out 3); the depth
    /// head's is the same with out 1.
    pub ray_patch: Option<RayPatchConfig>,
}

impl FamilyConfig for DefineConfig {
    fn base(&self) -> &'static str {
        "define"
    }
    fn name(&self) -> &'static str {
        "DeFiNe"
    }
    fn ray_patch(&self) -> Option<&RayPatchConfig> {
        self.ray_patch.as_ref()
    }
    fn has_depth(&self) -> bool {
        true
    }
    fn ray_kind(&self) -> RayKind {
        RayKind::UnitDepthPoint
    }
    fn position_octaves(&self) -> (&Octaves, &Octaves) {
        (&self.encoder.rays.pos_octaves, &self.decoder.rays.pos_octaves)
    }
    fn layer_counts(&self) -> Vec<(&'static str, usize)> {
        vec![
            ("encoder_kwargs.num_att_blocks", self.encoder.num_att_blocks),
            ("rp_kwargs.upsample", self.ray_patch.as_ref().map_or(0, |rp| rp.upsample)),
        ]
    }

    /// Two heads (rgb, depth), each one single-head cross-attention to the latents.
    fn decoder_attention_heads(&self) -> Vec<usize> {
        vec![1, 1]
    }

    fn depth_has_own_head(&self) -> bool {
        true
    }
}

impl DefineConfig {
    /// Resolves the model section of a DeFiNe run config. `path` names the file in errors.
    pub fn from_value(path: &str, raw: &Value) -> Result<DefineConfig, ModelError> {
        let ray_patch = match raw.get("decoder").and_then(Value::as_str) {
            Some("lightfield") => None,
            Some("featurefield") => {
                let rp = Section::new(path, raw, "rp_kwargs")?;
                if rp.get("out_dims").is_some() {
                    // The official DeFiNe passes out_dims itself: a second one is a TypeError there.
                    return Err(config_err(
                        path,
                        "`rp_kwargs.out_dims` must be absent for DeFiNe (the rgb and depth heads set 3 and 1)".into(),
                    ));
                }
                Some(RayPatchConfig::from_section(path, raw)?)
            }
            other => {
                return Err(config_err(
                    path,
                    format!(
                        "`decoder` must be \"lightfield\" (DeFiNe) or \"featurefield\" (RP-DeFiNe), found {:?}",
                        Quoted(other)
                    ),
                ))
            }
        };
        let enc = Section::new(path, raw, "encoder_kwargs")?;
        let encoder = DefineEncoderConfig {
            rays: RayFeatures::from_section(&enc)?,
            resnet_width: enc.usize("resnet_width", 64, Count::Width)?,
            num_latents: enc.usize("num_latents", 2048, Count::Width)?,
            latent_dim: enc.usize("latent_dim", 512, Count::Width)?,
            num_att_blocks: enc.usize("num_att_blocks", 8, Count::Layers)?,
            heads: enc.usize("heads", 8, Count::Width)?,
        };
        let dec = Section::new(path, raw, "decoder_kwargs")?;
        let decoder = DefineDecoderConfig {
            rays: RayFeatures::from_section(&dec)?,
            latent_dim: dec.usize("latent_dim", 512, Count::Width)?,
        };
        let config = DefineConfig { encoder, decoder, ray_patch };
        config.validate(path)?;
        Ok(config)
    }

    fn validate(&self, path: &str) -> Result<(), ModelError> {
        let (e, d) = (&self.encoder, &self.decoder);
        let widths = [
            ("encoder_kwargs.resnet_width", e.resnet_width),
            ("encoder_kwargs.num_latents", e.num_latents),
            ("encoder_kwargs.latent_dim", e.latent_dim),
            ("encoder_kwargs.heads", e.heads),
            ("decoder_kwargs.latent_dim", d.latent_dim),
        ];
        check_positive(path, &widths)?;
        check_widths(path, &widths)?;
        check_widths(path, &[("encoder_kwargs.resnet_width × 15", e.token_dim())])?;
        for (section, rays) in [("encoder_kwargs", &e.rays), ("decoder_kwargs", &d.rays)] {
            check_octaves(
                path,
                &[
                    (&format!("{section}.pos_octaves"), &rays.pos_octaves),
                    (&format!("{section}.ray_octaves"), &rays.ray_octaves),
                ],
            )?;
            if rays.pos_octaves.count == 0 || rays.ray_octaves.count == 0 {
                return Err(config_err(path, format!("`{section}.pos_octaves` and `ray_octaves` must be positive")));
            }
        }
        if e.latent_dim % e.heads != 0 {
            return Err(config_err(
                path,
                format!("`encoder_kwargs.latent_dim` ({}) must be divisible by `heads` ({})", e.latent_dim, e.heads),
            ));
        }
        if e.latent_dim / e.heads > 128 {
            return Err(config_err(path, "attention heads wider than 128 are not supported".into()));
        }
        if d.latent_dim != e.latent_dim {
            return Err(config_err(
                path,
                format!(
                    "`decoder_kwargs.latent_dim` ({}) must equal the encoder's latent width `encoder_kwargs.latent_dim` ({})",
                    d.latent_dim, e.latent_dim
                ),
            ));
        }
        Ok(())
    }

    /// Pixels per patch side: 1 for DeFiNe, 2^upsample for RP-DeFiNe.
    pub fn patch_size(&self) -> usize {
        self.ray_patch.as_ref().map_or(1, RayPatchConfig::patch_size)
    }

    /// The attention decoders' output width: 3 (rgb) and 1 (depth), or the conv features for both heads.
    pub fn head_dims(&self) -> (usize, usize) {
        self.ray_patch.as_ref().map_or((3, 1), |rp| (rp.conv_features, rp.conv_features))
    }
}
