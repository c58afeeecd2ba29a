//! `base: srt`: the config of SRT (`decoder: lightfield`) and RP-SRT (`decoder: featurefield`), as the
//! official `SRT` model class reads it (tberriel/RayPatchQuerying `src/model.py`, `encoder.py`, `decoder.py`).

use serde_json::Value;

use super::{
    check_octaves, check_positive, check_widths, config_err, Count, FamilyConfig, Octaves, RayKind, Section,
    MAX_CONV_BLOCKS,
};
use crate::error::{ModelError, Quoted};

#[derive(Clone, Debug, PartialEq)]
pub struct EncoderConfig {
    pub num_conv_blocks: usize,
    pub num_att_blocks: usize,
    pub pos_octaves: Octaves,
    pub ray_octaves: Octaves,
    pub batch_norm: bool,
    /// Hidden width of the first conv block; its output is twice this, then each block doubles.
    pub conv_hidden: usize,
    /// Width of the latent tokens (per_patch_linear output, transformer width).
    pub token_dim: usize,
    pub heads: usize,
    pub dim_head: usize,
    pub ff_hidden: usize,
}

/// The official `RayPredictor`: query encodings, input MLP and cross-attention layers to the latent. SRT's
/// decoder and OSRT's allocation transformer are one each.
#[derive(Clone, Debug, PartialEq)]
pub struct RayPredictorConfig {
    pub num_att_blocks: usize,
    pub pos_octaves: Octaves,
    pub ray_octaves: Octaves,
    /// Width of the keys and values (= the latent width: SRT's tokens, OSRT's slots).
    pub kv_dim: usize,
    pub heads: usize,
    pub dim_head: usize,
    pub ff_hidden: usize,
    pub input_mlp_hidden: usize,
}

#[derive(Clone, Debug, PartialEq)]
pub struct DecoderConfig {
    pub ray_predictor: RayPredictorConfig,
    pub out_mlp_hidden: usize,
    /// Width of the attention decoder's output: 3 or 4 (lightfield) or the Ray-Patch conv features.
    pub out_dims: usize,
}

#[derive(Clone, Debug, PartialEq)]
pub struct RayPatchConfig {
    /// Number of 2× upsampling blocks; the patch size is k = 2^upsample.
    pub upsample: usize,
    pub conv_features: usize,
    pub batch_norm: bool,
    /// 3 (rgb) or 4 (rgb + log-depth).
    pub out_dims: usize,
    /// (h_out, w_out) when set: the official decoder nearest-resizes its output to this size. The engine
    /// resizes to the target size instead (the official runs set h_out × w_out to their image size), which
    /// lets such a model render sizes that k does not divide (the old repo's k=8 at 60×80).
    pub resize_out: Option<(usize, usize)>,
    /// The patch grid the model was configured with (h_in, w_in); informational.
    pub grid_in: (usize, usize),
}

/// SRT and RP-SRT.
#[derive(Clone, Debug, PartialEq)]
pub struct SrtConfig {
    pub encoder: EncoderConfig,
    pub decoder: DecoderConfig,
    /// Present for `decoder: featurefield` (RP-SRT), absent for `lightfield` (SRT).
    pub ray_patch: Option<RayPatchConfig>,
}

impl EncoderConfig {
    /// The `encoder_kwargs` of an `SRTEncoder` (the SRT encoder, or the one inside `OSRTEncoder`), with the
    /// owning constructor's default `(num_conv_blocks, num_att_blocks)`.
    pub(crate) fn from_section(path: &str, raw: &Value, default_blocks: (usize, usize)) -> Result<Self, ModelError> {
        let enc = Section::new(path, raw, "encoder_kwargs")?;
        if enc.bool("max_pooling", false)? {
            return Err(config_err(path, "`encoder_kwargs.max_pooling: true` is not supported".into()));
        }
        let num_octaves = enc.usize("num_octaves", 15, Count::Octaves)?;
        let latent_dim = enc.usize("latent_dim", 768, Count::Width)?;
        let encoder = EncoderConfig {
            num_conv_blocks: enc.usize("num_conv_blocks", default_blocks.0, Count::Layers)?,
            num_att_blocks: enc.usize("num_att_blocks", default_blocks.1, Count::Layers)?,
            pos_octaves: Octaves { count: num_octaves, start: enc.f64("pos_start_octave", 0.0)?, end: None },
            ray_octaves: Octaves { count: num_octaves, start: 0.0, end: None },
            batch_norm: enc.batch_norm()?,
            conv_hidden: enc.usize("conv_hidden", 96, Count::Width)?,
            token_dim: enc.usize("token_dim", 768, Count::Width)?,
            heads: enc.usize("heads", 12, Count::Width)?,
            dim_head: enc.usize("dim_head", 64, Count::Width)?,
            ff_hidden: 2 * latent_dim,
        };
        encoder.validate(path)?;
        Ok(encoder)
    }

    fn validate(&self, path: &str) -> Result<(), ModelError> {
        let e = self;
        check_positive(
            path,
            &[
                ("encoder_kwargs.num_conv_blocks", e.num_conv_blocks),
                ("encoder_kwargs.num_octaves", e.pos_octaves.count),
                ("encoder_kwargs.conv_hidden", e.conv_hidden),
                ("encoder_kwargs.token_dim", e.token_dim),
                ("encoder_kwargs.heads", e.heads),
                ("encoder_kwargs.dim_head", e.dim_head),
                ("encoder_kwargs.latent_dim", e.ff_hidden),
            ],
        )?;
        // Counts and widths beyond these cannot be real models (no weight or image could be stored), and
        // bounding them keeps every size computed from them far from integer overflow.
        if e.num_conv_blocks > MAX_CONV_BLOCKS {
            return Err(config_err(
                path,
                format!("`encoder_kwargs.num_conv_blocks` is {}; at most {MAX_CONV_BLOCKS}", e.num_conv_blocks),
            ));
        }
        check_widths(
            path,
            &[
                (
                    "encoder_kwargs.conv_hidden (doubled per conv block)",
                    e.conv_hidden.saturating_mul(1 << e.num_conv_blocks),
                ),
                ("encoder_kwargs.token_dim", e.token_dim),
                ("encoder_kwargs.heads x dim_head", e.heads.saturating_mul(e.dim_head)),
                ("encoder_kwargs.latent_dim", e.ff_hidden),
            ],
        )?;
        if e.pos_octaves.count > 32 {
            return Err(config_err(
                path,
                format!("`encoder_kwargs.num_octaves` is {}; at most 32 are supported", e.pos_octaves.count),
            ));
        }
        check_octaves(path, &[("encoder_kwargs.pos_start_octave", &e.pos_octaves)])?;
        if e.dim_head > 128 {
            return Err(config_err(path, "attention heads wider than 128 are not supported".into()));
        }
        Ok(())
    }

    /// Channels of the encoder's input: RGB, then the position and ray encodings.
    pub fn input_dim(&self) -> usize {
        3 + 6 * (self.pos_octaves.count + self.ray_octaves.count)
    }
}

impl RayPatchConfig {
    /// The `rp_kwargs` of a `featurefield` model (the official `RayPatchDecoder` kwargs).
    pub(crate) fn from_section(path: &str, raw: &Value) -> Result<Self, ModelError> {
        let rp = Section::new(path, raw, "rp_kwargs")?;
        let resize_out = match (rp.get("h_out"), rp.get("w_out")) {
            (Some(_), Some(_)) => Some((rp.usize("h_out", 0, Count::Side)?, rp.usize("w_out", 0, Count::Side)?)),
            _ => None,
        };
        let config = RayPatchConfig {
            upsample: rp.usize("upsample", 3, Count::Layers)?,
            conv_features: rp.usize("conv_features", 128, Count::Width)?,
            batch_norm: rp.batch_norm()?,
            out_dims: rp.usize("out_dims", 3, Count::Width)?,
            resize_out,
            grid_in: (rp.usize("h_in", 16, Count::Side)?, rp.usize("w_in", 16, Count::Side)?),
        };
        check_widths(path, &[("rp_kwargs.conv_features", config.conv_features)])?;
        if config.upsample == 0 || config.upsample > 6 {
            return Err(config_err(path, format!("`rp_kwargs.upsample` must be 1..6, found {}", config.upsample)));
        }
        if config.conv_features >> config.upsample < 2 {
            return Err(config_err(
                path,
                format!(
                    "`rp_kwargs.conv_features` {} must stay above 1 after {} halvings",
                    config.conv_features, config.upsample
                ),
            ));
        }
        check_image_channels(path, "rp_kwargs.out_dims", config.out_dims)?;
        Ok(config)
    }

    /// Pixels per patch side: 2^upsample.
    pub fn patch_size(&self) -> usize {
        1 << self.upsample
    }
}

impl RayPredictorConfig {
    /// The ray predictor of a `decoder_kwargs` section: `latent_dim` (default `kv_default`) wide keys and
    /// values, `heads` heads of `int(latent_dim / heads)` as in the official RayPredictor, FF `2·latent_dim`.
    pub(crate) fn from_section(
        dec: &Section,
        kv_default: usize,
        pos_octaves: Octaves,
        ray_octaves: Octaves,
    ) -> Result<Self, ModelError> {
        let kv_dim = dec.usize("latent_dim", kv_default, Count::Width)?;
        let heads = dec.usize("heads", 12, Count::Width)?;
        Ok(RayPredictorConfig {
            num_att_blocks: dec.usize("num_att_blocks", 2, Count::Layers)?,
            pos_octaves,
            ray_octaves,
            kv_dim,
            heads,
            dim_head: kv_dim.checked_div(heads).unwrap_or(0),
            ff_hidden: 2 * kv_dim,
            input_mlp_hidden: dec.usize("input_mlp_hidden", 360, Count::Width)?,
        })
    }

    /// `pos_key` names the position encoding in errors.
    pub(crate) fn validate(&self, path: &str, pos_key: &str) -> Result<(), ModelError> {
        check_positive(
            path,
            &[
                ("decoder_kwargs.latent_dim", self.kv_dim),
                ("decoder_kwargs.heads", self.heads),
                ("decoder_kwargs.input_mlp_hidden", self.input_mlp_hidden),
                (
                    "decoder_kwargs.pos_octaves + ray_octaves",
                    self.pos_octaves.count.saturating_add(self.ray_octaves.count),
                ),
            ],
        )?;
        check_widths(
            path,
            &[("decoder_kwargs.latent_dim", self.kv_dim), ("decoder_kwargs.input_mlp_hidden", self.input_mlp_hidden)],
        )?;
        check_octaves(path, &[(pos_key, &self.pos_octaves), ("decoder_kwargs.ray_octaves", &self.ray_octaves)])?;
        if self.dim_head > 128 {
            return Err(config_err(path, "attention heads wider than 128 are not supported".into()));
        }
        Ok(())
    }

    /// Width of a query: position and ray encodings.
    pub fn query_dim(&self) -> usize {
        6 * (self.pos_octaves.count + self.ray_octaves.count)
    }
}

/// The layer counts of an SRT encoder, a ray predictor and a Ray-Patch decoder, by config key (for
/// [`ModelConfig::check_counts`](super::ModelConfig::check_counts)).
pub(crate) fn layer_counts(
    encoder: &EncoderConfig,
    ray_predictor: &RayPredictorConfig,
    ray_patch: Option<&RayPatchConfig>,
) -> Vec<(&'static str, usize)> {
    vec![
        ("encoder_kwargs.num_conv_blocks", encoder.num_conv_blocks),
        ("encoder_kwargs.num_att_blocks", encoder.num_att_blocks),
        ("decoder_kwargs.num_att_blocks", ray_predictor.num_att_blocks),
        ("rp_kwargs.upsample", ray_patch.map_or(0, |rp| rp.upsample)),
    ]
}

/// Checks the channels of a model's final image: 3 (rgb) or 4 (rgb + log-depth).
pub(crate) fn check_image_channels(path: &str, key: &str, channels: usize) -> Result<(), ModelError> {
    if channels != 3 && channels != 4 {
        return Err(config_err(path, format!("`{key}` must be 3 or 4, found {channels}")));
    }
    Ok(())
}

impl FamilyConfig for SrtConfig {
    fn base(&self) -> &'static str {
        "srt"
    }
    fn name(&self) -> &'static str {
        "SRT"
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
        (&self.encoder.pos_octaves, &self.decoder.ray_predictor.pos_octaves)
    }
    fn layer_counts(&self) -> Vec<(&'static str, usize)> {
        layer_counts(&self.encoder, &self.decoder.ray_predictor, self.ray_patch.as_ref())
    }

    fn decoder_attention_heads(&self) -> Vec<usize> {
        vec![self.decoder.ray_predictor.heads]
    }

    fn depth_has_own_head(&self) -> bool {
        false
    }
}

impl SrtConfig {
    /// Resolves the model section of an SRT run config. `path` names the file in errors.
    pub fn from_value(path: &str, raw: &Value) -> Result<SrtConfig, ModelError> {
        let ray_patch_decoder = match raw.get("decoder").and_then(Value::as_str) {
            Some("lightfield") => false,
            Some("featurefield") => true,
            other => {
                return Err(config_err(
                    path,
                    format!(
                        "`decoder` must be \"lightfield\" (SRT) or \"featurefield\" (RP-SRT), found {:?}",
                        Quoted(other)
                    ),
                ))
            }
        };

        let encoder = EncoderConfig::from_section(path, raw, (4, 10))?;
        let ray_patch = if ray_patch_decoder { Some(RayPatchConfig::from_section(path, raw)?) } else { None };

        let dec = Section::new(path, raw, "decoder_kwargs")?;
        let pos_octaves = dec.octaves("pos_octaves", "pos_start_octave", "pos_end_octave", 15, 0.0)?;
        let ray_octaves = dec.octaves("ray_octaves", "ray_start_octave", "ray_end_octave", 15, 0.0)?;
        let decoder = DecoderConfig {
            ray_predictor: RayPredictorConfig::from_section(&dec, 768, pos_octaves, ray_octaves)?,
            out_mlp_hidden: dec.usize("out_mlp_hidden", 1536, Count::Width)?,
            // The official SRT model overrides the decoder's out_dims with the conv features for Ray-Patch.
            out_dims: match &ray_patch {
                Some(rp) => rp.conv_features,
                None => dec.usize("out_dims", 3, Count::Width)?,
            },
        };

        let config = SrtConfig { encoder, decoder, ray_patch };
        config.validate(path)?;
        Ok(config)
    }

    fn validate(&self, path: &str) -> Result<(), ModelError> {
        let d = &self.decoder;
        d.ray_predictor.validate(path, "decoder_kwargs.pos_octaves")?;
        check_positive(path, &[("decoder_kwargs.out_mlp_hidden", d.out_mlp_hidden)])?;
        check_widths(path, &[("decoder_kwargs.out_mlp_hidden", d.out_mlp_hidden)])?;
        if d.ray_predictor.kv_dim != self.encoder.token_dim {
            return Err(config_err(
                path,
                format!(
                    "`decoder_kwargs.latent_dim` ({}) must equal the encoder token width ({})",
                    d.ray_predictor.kv_dim, self.encoder.token_dim
                ),
            ));
        }
        if self.ray_patch.is_none() {
            check_image_channels(path, "decoder_kwargs.out_dims", d.out_dims)?;
        }
        Ok(())
    }

    /// Pixels per patch side: 1 for SRT, 2^upsample for RP-SRT.
    pub fn patch_size(&self) -> usize {
        self.ray_patch.as_ref().map_or(1, RayPatchConfig::patch_size)
    }

    /// Channels of the final image before the sigmoid: 3, or 4 with log-depth.
    pub fn image_channels(&self) -> usize {
        self.ray_patch.as_ref().map_or(self.decoder.out_dims, |rp| rp.out_dims)
    }

    /// Width of a decoder query: position and ray encodings.
    pub fn query_dim(&self) -> usize {
        self.decoder.ray_predictor.query_dim()
    }
}
