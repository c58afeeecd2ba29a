//! `base: osrt`: the config of OSRT (`decoder: lightfield`) and RP-OSRT (`decoder: featurefield`), as the
//! official `OSRT` model class reads it (tberriel/RayPatchQuerying `src/model.py`; `OSRTEncoder` in
//! `src/encoder.py`, `SlotAttention` in `src/layers.py`, `SlotMixerDecoder` in `src/decoder.py`).
//!
//! The official modules hard-code most OSRT widths (slot attention hidden 3072; the slot mixer's 1536-wide
//! allocation transformer, mixing block and render MLP); raypatch extension keys name them so that small
//! models can be built, defaulting to the official values (docs/FORMATS.md).

use serde_json::Value;

use super::srt::{check_image_channels, layer_counts};
use super::{check_positive, check_widths, config_err, Count, FamilyConfig, Octaves, RayKind, Section};
use super::{EncoderConfig, RayPatchConfig, RayPredictorConfig};
use crate::error::{ModelError, Quoted};

/// `SlotAttention` inside `OSRTEncoder`.
#[derive(Clone, Debug, PartialEq)]
pub struct SlotAttentionConfig {
    pub num_slots: usize,
    pub slot_dim: usize,
    /// Width of the residual MLP (official: 3072, never passed by `OSRTEncoder`).
    pub hidden: usize,
    pub iters: usize,
}

/// `SlotMixerDecoder`: allocation transformer (a `RayPredictor` with input MLP, no output MLP), mixing block,
/// render MLP.
#[derive(Clone, Debug, PartialEq)]
pub struct SlotMixerConfig {
    /// The allocation transformer; its keys and values are the slot width (official 1536).
    pub allocation: RayPredictorConfig,
    /// Width of the mixing block's queries and keys (official 1536).
    pub att_dim: usize,
    /// `MixingBlock(layer_norm=...)`: LayerNorms on the queries and on the slot mix.
    pub layer_norm: bool,
    /// Width of the render MLP's four hidden layers (official 1536).
    pub render_hidden: usize,
    /// The render MLP's output: 3 (rgb) for OSRT, the Ray-Patch conv features for RP-OSRT.
    pub out_dims: usize,
}

/// OSRT and RP-OSRT.
#[derive(Clone, Debug, PartialEq)]
pub struct OsrtConfig {
    /// The SRT encoder inside `OSRTEncoder`.
    pub encoder: EncoderConfig,
    pub slot_attention: SlotAttentionConfig,
    pub decoder: SlotMixerConfig,
    /// Present for `decoder: featurefield` (RP-OSRT), absent for `lightfield` (OSRT).
    pub ray_patch: Option<RayPatchConfig>,
}

impl FamilyConfig for OsrtConfig {
    fn base(&self) -> &'static str {
        "osrt"
    }
    fn name(&self) -> &'static str {
        "OSRT"
    }
    fn ray_patch(&self) -> Option<&RayPatchConfig> {
        self.ray_patch.as_ref()
    }
    fn has_depth(&self) -> bool {
        self.image_channels() == 4
    }
    fn ray_kind(&self) -> RayKind {
        RayKind::UnitDirection
    }
    fn position_octaves(&self) -> (&Octaves, &Octaves) {
        (&self.encoder.pos_octaves, &self.decoder.allocation.pos_octaves)
    }
    fn layer_counts(&self) -> Vec<(&'static str, usize)> {
        layer_counts(&self.encoder, &self.decoder.allocation, self.ray_patch.as_ref())
    }

    /// The allocation transformer's cross-attention, and the mixing block's single-head softmax over the slots.
    fn decoder_attention_heads(&self) -> Vec<usize> {
        vec![self.decoder.allocation.heads, 1]
    }

    fn depth_has_own_head(&self) -> bool {
        false
    }
}

impl OsrtConfig {
    /// Resolves the model section of an OSRT run config. `path` names the file in errors.
    pub fn from_value(path: &str, raw: &Value) -> Result<OsrtConfig, ModelError> {
        let ray_patch = match raw.get("decoder").and_then(Value::as_str) {
            Some("lightfield") => None,
            Some("featurefield") => Some(RayPatchConfig::from_section(path, raw)?),
            other => {
                return Err(config_err(
                    path,
                    format!(
                        "`decoder` must be \"lightfield\" (OSRT) or \"featurefield\" (RP-OSRT), found {:?}",
                        Quoted(other)
                    ),
                ))
            }
        };
        // OSRTEncoder's own defaults: 3 conv blocks, 5 attention blocks.
        let encoder = EncoderConfig::from_section(path, raw, (3, 5))?;
        let enc = Section::new(path, raw, "encoder_kwargs")?;
        if enc.bool("randomize_initial_slots", false)? {
            return Err(config_err(
                path,
                "`encoder_kwargs.randomize_initial_slots: true` is not supported (slots are sampled at random)".into(),
            ));
        }
        let slot_attention = SlotAttentionConfig {
            num_slots: enc.usize("num_slots", 6, Count::Width)?,
            slot_dim: enc.usize("slot_dim", 1536, Count::Width)?,
            hidden: enc.usize("slot_hidden", 3072, Count::Width)?,
            iters: enc.usize("slot_iters", 1, Count::Iterations)?,
        };

        let dec = Section::new(path, raw, "decoder_kwargs")?;
        // SlotMixerDecoder passes only pos_start_octave to its RayPredictor: 15 + 15 octaves.
        let pos_octaves = Octaves { count: 15, start: dec.f64("pos_start_octave", 0.0)?, end: None };
        let ray_octaves = Octaves { count: 15, start: 0.0, end: None };
        let decoder = SlotMixerConfig {
            allocation: RayPredictorConfig::from_section(&dec, 1536, pos_octaves, ray_octaves)?,
            att_dim: dec.usize("att_dim", 1536, Count::Width)?,
            layer_norm: dec.bool("layer_norm", false)?,
            render_hidden: dec.usize("render_mlp_hidden", 1536, Count::Width)?,
            // The official OSRT overrides the decoder's out_dims: 3, or the conv features for Ray-Patch.
            out_dims: ray_patch.as_ref().map_or(3, |rp| rp.conv_features),
        };
        let config = OsrtConfig { encoder, slot_attention, decoder, ray_patch };
        config.validate(path)?;
        Ok(config)
    }

    fn validate(&self, path: &str) -> Result<(), ModelError> {
        let (s, d) = (&self.slot_attention, &self.decoder);
        d.allocation.validate(path, "decoder_kwargs.pos_start_octave")?;
        let widths = [
            ("encoder_kwargs.slot_dim", s.slot_dim),
            ("encoder_kwargs.slot_hidden", s.hidden),
            ("decoder_kwargs.att_dim", d.att_dim),
            ("decoder_kwargs.render_mlp_hidden", d.render_hidden),
        ];
        check_positive(path, &widths)?;
        check_positive(path, &[("encoder_kwargs.num_slots", s.num_slots), ("encoder_kwargs.slot_iters", s.iters)])?;
        check_widths(path, &widths)?;
        check_widths(path, &[("encoder_kwargs.num_slots", s.num_slots)])?;
        if d.allocation.kv_dim != s.slot_dim {
            return Err(config_err(
                path,
                format!(
                    "`decoder_kwargs.latent_dim` ({}) must equal the slot width `encoder_kwargs.slot_dim` ({})",
                    d.allocation.kv_dim, s.slot_dim
                ),
            ));
        }
        if self.ray_patch.is_none() {
            check_image_channels(path, "decoder_kwargs.out_dims", d.out_dims)?;
        }
        Ok(())
    }

    /// Pixels per patch side: 1 for OSRT, 2^upsample for RP-OSRT.
    pub fn patch_size(&self) -> usize {
        self.ray_patch.as_ref().map_or(1, RayPatchConfig::patch_size)
    }

    /// Channels of the final image before the sigmoid: 3, or 4 with log-depth (RP-OSRT `rp_kwargs.out_dims`).
    pub fn image_channels(&self) -> usize {
        self.ray_patch.as_ref().map_or(self.decoder.out_dims, |rp| rp.out_dims)
    }

    /// Width of a decoder query: position and ray encodings.
    pub fn query_dim(&self) -> usize {
        self.decoder.allocation.query_dim()
    }
}
