//! The model config: the official `config.yaml` model section (stored as JSON in the safetensors metadata),
//! resolved into every dimension the engine needs. Absent keys take the official constructors' defaults;
//! the raypatch extension keys (docs/FORMATS.md) default to the widths the official code hard-codes.

use serde_json::Value;

use crate::error::ModelError;
use crate::scene::{TargetGrid, TargetViews};

/// One Fourier encoding: `octaves` multipliers starting at `start` (powers of two), or a linspace
/// from `start` to `end` when `end` is set (the DeFiNe form).
#[derive(Clone, Debug, PartialEq)]
pub struct Octaves {
    pub count: usize,
    pub start: f64,
    pub end: Option<f64>,
}

impl Octaves {
    /// Multiplier `i`: 2^(start + i)·π, or the `i`-th linspace value from start to end, times π.
    pub fn multiplier(&self, i: usize) -> f64 {
        let octave = match self.end {
            None => (self.start + i as f64).exp2(),
            Some(end) if self.count > 1 => self.start + (end - self.start) * i as f64 / (self.count - 1) as f64,
            Some(_) => self.start,
        };
        octave * std::f64::consts::PI
    }

    /// The largest multiplier in magnitude (they are monotonic, so the first or the last).
    pub fn max_multiplier(&self) -> f64 {
        let last = self.count.saturating_sub(1);
        self.multiplier(0).abs().max(self.multiplier(last).abs())
    }

    /// The first multiplier that is not a normal finite float32, if any: one that overflows makes every
    /// encoding NaN, one that underflows encodes nothing.
    pub fn multipliers_out_of_f32_range(&self) -> Option<f64> {
        // A linspace may start at 0; a power of two never reaches it.
        let normal = |m: f64| {
            (m == 0.0 && self.end.is_some()) || (f32::MIN_POSITIVE as f64..=f32::MAX as f64).contains(&m.abs())
        };
        [0, self.count.saturating_sub(1)].into_iter().map(|i| self.multiplier(i)).find(|&m| !normal(m))
    }
}

/// Most encoder conv blocks: each halves the image, so 14 take the largest accepted image to one pixel.
pub const MAX_CONV_BLOCKS: usize = 14;
/// Widest layer accepted: a square weight of this width alone would be 4 TiB.
pub const MAX_WIDTH: usize = 1 << 20;

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

#[derive(Clone, Debug, PartialEq)]
pub struct DecoderConfig {
    pub num_att_blocks: usize,
    pub pos_octaves: Octaves,
    pub ray_octaves: Octaves,
    /// Width of the keys and values (= the latent token width).
    pub kv_dim: usize,
    pub heads: usize,
    pub dim_head: usize,
    pub ff_hidden: usize,
    pub input_mlp_hidden: usize,
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

#[derive(Clone, Debug, PartialEq)]
pub struct ModelConfig {
    pub encoder: EncoderConfig,
    pub decoder: DecoderConfig,
    /// Present for `decoder: featurefield` (RP-SRT), absent for `lightfield` (SRT).
    pub ray_patch: Option<RayPatchConfig>,
    /// The config as stored in the file.
    pub raw: Value,
}

/// Reads typed keys out of one section, naming the section and key in errors.
struct Section<'a> {
    path: &'a str,
    name: &'a str,
    value: Option<&'a Value>,
}

impl<'a> Section<'a> {
    fn new(path: &'a str, root: &'a Value, name: &'a str) -> Result<Self, ModelError> {
        let value = root.get(name).filter(|v| !v.is_null());
        if let Some(v) = value {
            if !v.is_object() {
                return Err(config_err(path, format!("`{name}` must be a mapping, found {v}")));
            }
        }
        Ok(Section { path, name, value })
    }

    fn get(&self, key: &str) -> Option<&'a Value> {
        self.value.and_then(|v| v.get(key)).filter(|v| !v.is_null())
    }

    fn usize(&self, key: &str, default: usize) -> Result<usize, ModelError> {
        match self.get(key) {
            None => Ok(default),
            Some(v) => v.as_u64().map(|x| x as usize).ok_or_else(|| {
                config_err(self.path, format!("`{}.{key}` must be a non-negative integer, found {v}", self.name))
            }),
        }
    }

    fn f64(&self, key: &str, default: f64) -> Result<f64, ModelError> {
        self.opt_f64(key).map(|v| v.unwrap_or(default))
    }

    fn opt_f64(&self, key: &str) -> Result<Option<f64>, ModelError> {
        match self.get(key) {
            None => Ok(None),
            Some(v) => v
                .as_f64()
                .map(Some)
                .ok_or_else(|| config_err(self.path, format!("`{}.{key}` must be a number, found {v}", self.name))),
        }
    }

    fn bool(&self, key: &str, default: bool) -> Result<bool, ModelError> {
        match self.get(key) {
            None => Ok(default),
            Some(v) => v.as_bool().ok_or_else(|| {
                config_err(self.path, format!("`{}.{key}` must be true or false, found {v}", self.name))
            }),
        }
    }

    /// `norm: Batch` → true; absent or null → false; anything else is an error.
    fn batch_norm(&self) -> Result<bool, ModelError> {
        match self.get("norm") {
            None => Ok(false),
            Some(Value::String(s)) if s == "Batch" => Ok(true),
            Some(v) => Err(config_err(self.path, format!("`{}.norm` must be \"Batch\" or null, found {v}", self.name))),
        }
    }

    fn octaves(
        &self,
        count_key: &str,
        start_key: &str,
        end_key: &str,
        count: usize,
        start: f64,
    ) -> Result<Octaves, ModelError> {
        Ok(Octaves {
            count: self.usize(count_key, count)?,
            start: self.f64(start_key, start)?,
            end: self.opt_f64(end_key)?,
        })
    }
}

fn config_err(path: &str, reason: String) -> ModelError {
    ModelError::Config { path: path.to_string(), reason }
}

impl ModelConfig {
    /// Resolves the model section of a run config. `path` names the file in errors.
    pub fn from_value(path: &str, raw: Value) -> Result<ModelConfig, ModelError> {
        if !raw.is_object() {
            return Err(config_err(path, format!("the model config must be a mapping, found {raw}")));
        }
        match raw.get("base").and_then(Value::as_str) {
            Some("srt") => {}
            Some(other) => {
                return Err(config_err(
                    path,
                    format!("model base `{other}` is not supported (raypatch runs `srt`: SRT and RP-SRT)"),
                ))
            }
            None => return Err(config_err(path, "missing `base` (expected \"srt\")".into())),
        }
        let ray_patch_decoder = match raw.get("decoder").and_then(Value::as_str) {
            Some("lightfield") => false,
            Some("featurefield") => true,
            other => {
                return Err(config_err(
                    path,
                    format!("`decoder` must be \"lightfield\" (SRT) or \"featurefield\" (RP-SRT), found {other:?}"),
                ))
            }
        };

        let enc = Section::new(path, &raw, "encoder_kwargs")?;
        if enc.bool("max_pooling", false)? {
            return Err(config_err(path, "`encoder_kwargs.max_pooling: true` is not supported".into()));
        }
        let num_octaves = enc.usize("num_octaves", 15)?;
        let latent_dim = enc.usize("latent_dim", 768)?;
        let encoder = EncoderConfig {
            num_conv_blocks: enc.usize("num_conv_blocks", 4)?,
            num_att_blocks: enc.usize("num_att_blocks", 10)?,
            pos_octaves: Octaves { count: num_octaves, start: enc.f64("pos_start_octave", 0.0)?, end: None },
            ray_octaves: Octaves { count: num_octaves, start: 0.0, end: None },
            batch_norm: enc.batch_norm()?,
            conv_hidden: enc.usize("conv_hidden", 96)?,
            token_dim: enc.usize("token_dim", 768)?,
            heads: enc.usize("heads", 12)?,
            dim_head: enc.usize("dim_head", 64)?,
            ff_hidden: 2 * latent_dim,
        };

        let rp = Section::new(path, &raw, "rp_kwargs")?;
        let ray_patch = if ray_patch_decoder {
            let resize_out = match (rp.get("h_out"), rp.get("w_out")) {
                (Some(_), Some(_)) => Some((rp.usize("h_out", 0)?, rp.usize("w_out", 0)?)),
                _ => None,
            };
            Some(RayPatchConfig {
                upsample: rp.usize("upsample", 3)?,
                conv_features: rp.usize("conv_features", 128)?,
                batch_norm: rp.batch_norm()?,
                out_dims: rp.usize("out_dims", 3)?,
                resize_out,
                grid_in: (rp.usize("h_in", 16)?, rp.usize("w_in", 16)?),
            })
        } else {
            None
        };

        let dec = Section::new(path, &raw, "decoder_kwargs")?;
        let kv_dim = dec.usize("latent_dim", 768)?;
        let heads = dec.usize("heads", 12)?;
        let decoder = DecoderConfig {
            num_att_blocks: dec.usize("num_att_blocks", 2)?,
            pos_octaves: dec.octaves("pos_octaves", "pos_start_octave", "pos_end_octave", 15, 0.0)?,
            ray_octaves: dec.octaves("ray_octaves", "ray_start_octave", "ray_end_octave", 15, 0.0)?,
            kv_dim,
            heads,
            // int(latent_dim / heads) as in the official RayPredictor.
            dim_head: kv_dim.checked_div(heads).unwrap_or(0),
            ff_hidden: 2 * kv_dim,
            input_mlp_hidden: dec.usize("input_mlp_hidden", 360)?,
            out_mlp_hidden: dec.usize("out_mlp_hidden", 1536)?,
            // The official SRT model overrides the decoder's out_dims with the conv features for Ray-Patch.
            out_dims: match &ray_patch {
                Some(rp) => rp.conv_features,
                None => dec.usize("out_dims", 3)?,
            },
        };

        let config = ModelConfig { encoder, decoder, ray_patch, raw };
        config.validate(path)?;
        Ok(config)
    }

    fn validate(&self, path: &str) -> Result<(), ModelError> {
        let e = &self.encoder;
        let d = &self.decoder;
        let positive = [
            ("encoder_kwargs.num_conv_blocks", e.num_conv_blocks),
            ("encoder_kwargs.num_octaves", e.pos_octaves.count),
            ("encoder_kwargs.conv_hidden", e.conv_hidden),
            ("encoder_kwargs.token_dim", e.token_dim),
            ("encoder_kwargs.heads", e.heads),
            ("encoder_kwargs.dim_head", e.dim_head),
            ("encoder_kwargs.latent_dim", e.ff_hidden),
            ("decoder_kwargs.latent_dim", d.kv_dim),
            ("decoder_kwargs.heads", d.heads),
            ("decoder_kwargs.input_mlp_hidden", d.input_mlp_hidden),
            ("decoder_kwargs.out_mlp_hidden", d.out_mlp_hidden),
            ("decoder_kwargs.pos_octaves + ray_octaves", d.pos_octaves.count.saturating_add(d.ray_octaves.count)),
        ];
        for (key, value) in positive {
            if value == 0 {
                return Err(config_err(path, format!("`{key}` must be positive")));
            }
        }
        for (key, octaves) in
            [("decoder_kwargs.pos_octaves", &d.pos_octaves), ("decoder_kwargs.ray_octaves", &d.ray_octaves)]
        {
            if octaves.count > 32 {
                return Err(config_err(
                    path,
                    format!("`{key}` is {}; at most 32 octaves are supported", octaves.count),
                ));
            }
        }
        if e.pos_octaves.count > 32 {
            return Err(config_err(
                path,
                format!("`encoder_kwargs.num_octaves` is {}; at most 32 are supported", e.pos_octaves.count),
            ));
        }
        // Counts and widths beyond these cannot be real models (no weight or image could be stored), and
        // bounding them keeps every size computed from them far from integer overflow.
        if e.num_conv_blocks > MAX_CONV_BLOCKS {
            return Err(config_err(
                path,
                format!("`encoder_kwargs.num_conv_blocks` is {}; at most {MAX_CONV_BLOCKS}", e.num_conv_blocks),
            ));
        }
        let widths = [
            (
                "encoder_kwargs.conv_hidden (doubled per conv block)",
                e.conv_hidden.saturating_mul(1 << e.num_conv_blocks),
            ),
            ("encoder_kwargs.token_dim", e.token_dim),
            ("encoder_kwargs.heads x dim_head", e.heads.saturating_mul(e.dim_head)),
            ("encoder_kwargs.latent_dim", e.ff_hidden),
            ("decoder_kwargs.latent_dim", d.kv_dim),
            ("decoder_kwargs.input_mlp_hidden", d.input_mlp_hidden),
            ("decoder_kwargs.out_mlp_hidden", d.out_mlp_hidden),
            ("rp_kwargs.conv_features", self.ray_patch.as_ref().map_or(0, |rp| rp.conv_features)),
        ];
        for (key, width) in widths {
            if width > MAX_WIDTH {
                return Err(config_err(path, format!("`{key}` is {width}; at most {MAX_WIDTH} is supported")));
            }
        }
        for (key, octaves) in [
            ("encoder_kwargs.pos_start_octave", &e.pos_octaves),
            ("decoder_kwargs.pos_octaves", &d.pos_octaves),
            ("decoder_kwargs.ray_octaves", &d.ray_octaves),
        ] {
            if let Some(m) = octaves.multipliers_out_of_f32_range() {
                return Err(config_err(
                    path,
                    format!("`{key}` gives a Fourier multiplier of {m:e}, outside float32's normal range"),
                ));
            }
        }
        if d.dim_head > 128 || e.dim_head > 128 {
            return Err(config_err(path, "attention heads wider than 128 are not supported".into()));
        }
        if d.kv_dim != e.token_dim {
            return Err(config_err(
                path,
                format!(
                    "`decoder_kwargs.latent_dim` ({}) must equal the encoder token width ({})",
                    d.kv_dim, e.token_dim
                ),
            ));
        }
        match &self.ray_patch {
            Some(rp) => {
                if rp.upsample == 0 || rp.upsample > 6 {
                    return Err(config_err(path, format!("`rp_kwargs.upsample` must be 1..6, found {}", rp.upsample)));
                }
                if rp.conv_features >> rp.upsample < 2 {
                    return Err(config_err(
                        path,
                        format!(
                            "`rp_kwargs.conv_features` {} must stay above 1 after {} halvings",
                            rp.conv_features, rp.upsample
                        ),
                    ));
                }
                if rp.out_dims != 3 && rp.out_dims != 4 {
                    return Err(config_err(
                        path,
                        format!("`rp_kwargs.out_dims` must be 3 or 4, found {}", rp.out_dims),
                    ));
                }
            }
            None => {
                if d.out_dims != 3 && d.out_dims != 4 {
                    return Err(config_err(
                        path,
                        format!("`decoder_kwargs.out_dims` must be 3 or 4, found {}", d.out_dims),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether the decoder resizes its output to the target size (see [`RayPatchConfig::resize_out`]).
    pub fn resizes_output(&self) -> bool {
        self.ray_patch.as_ref().is_some_and(|rp| rp.resize_out.is_some())
    }

    /// The image size and ray resolution of target views for this model (see [`TargetViews::grid`]).
    pub fn target_grid(&self, targets: &TargetViews, path: &str) -> Result<TargetGrid, ModelError> {
        targets.grid(self.patch_size(), self.resizes_output(), path)
    }

    /// Pixels per patch side: 1 for SRT, 2^upsample for RP-SRT.
    pub fn patch_size(&self) -> usize {
        self.ray_patch.as_ref().map_or(1, |rp| 1 << rp.upsample)
    }

    /// Channels of the final image before the sigmoid: 3, or 4 with log-depth.
    pub fn image_channels(&self) -> usize {
        self.ray_patch.as_ref().map_or(self.decoder.out_dims, |rp| rp.out_dims)
    }

    /// Input images must be divisible by this (each conv block halves the size).
    pub fn input_divisor(&self) -> usize {
        1 << self.encoder.num_conv_blocks
    }

    /// Width of a decoder query: position and ray encodings.
    pub fn query_dim(&self) -> usize {
        6 * (self.decoder.pos_octaves.count + self.decoder.ray_octaves.count)
    }

    /// Channels of the encoder's input: RGB, then the position and ray encodings.
    pub fn encoder_input_dim(&self) -> usize {
        3 + 6 * (self.encoder.pos_octaves.count + self.encoder.ray_octaves.count)
    }

    /// Output channels of each encoder conv block.
    pub fn encoder_conv_widths(&self) -> Vec<(usize, usize, usize)> {
        let e = &self.encoder;
        let mut widths = vec![(self.encoder_input_dim(), e.conv_hidden, 2 * e.conv_hidden)];
        let mut c = 2 * e.conv_hidden;
        for _ in 1..e.num_conv_blocks {
            widths.push((c, c, 2 * c));
            c *= 2;
        }
        widths
    }

    /// Checks the config's layer counts against a file holding `tensors` tensors, before anything as large as
    /// a count is built: each layer has at least one tensor, so a count above the file's is a lie.
    pub fn check_counts(&self, path: &str, tensors: usize) -> Result<(), ModelError> {
        let counts = [
            ("encoder_kwargs.num_conv_blocks", self.encoder.num_conv_blocks),
            ("encoder_kwargs.num_att_blocks", self.encoder.num_att_blocks),
            ("decoder_kwargs.num_att_blocks", self.decoder.num_att_blocks),
            ("rp_kwargs.upsample", self.ray_patch.as_ref().map_or(0, |rp| rp.upsample)),
        ];
        for (key, count) in counts {
            if count > tensors {
                return Err(config_err(
                    path,
                    format!("`{key}` is {count}, but the file holds only {tensors} tensors (at least one per layer)"),
                ));
            }
        }
        Ok(())
    }

    /// Every tensor of the official state_dict for this config (without `num_batches_tracked`), in order.
    pub fn expected_tensors(&self) -> Vec<(String, Vec<usize>)> {
        let mut t: Vec<(String, Vec<usize>)> = Vec::new();
        let e = &self.encoder;
        let d = &self.decoder;
        let batch_norm = |t: &mut Vec<(String, Vec<usize>)>, prefix: &str, c: usize| {
            for name in ["weight", "bias", "running_mean", "running_var"] {
                t.push((format!("{prefix}.{name}"), vec![c]));
            }
        };
        let layer_norm = |t: &mut Vec<(String, Vec<usize>)>, prefix: &str, c: usize| {
            t.push((format!("{prefix}.weight"), vec![c]));
            t.push((format!("{prefix}.bias"), vec![c]));
        };
        let linear = |t: &mut Vec<(String, Vec<usize>)>, prefix: &str, out: usize, inp: usize, bias: bool| {
            t.push((format!("{prefix}.weight"), vec![out, inp]));
            if bias {
                t.push((format!("{prefix}.bias"), vec![out]));
            }
        };

        let widths = self.encoder_conv_widths();
        for (i, &(cin, hidden, cout)) in widths.iter().enumerate() {
            let p = format!("encoder.conv_blocks.{i}.layers");
            t.push((format!("{p}.0.weight"), vec![hidden, cin, 3, 3]));
            if e.batch_norm {
                batch_norm(&mut t, &format!("{p}.1"), hidden);
            }
            t.push((format!("{p}.3.weight"), vec![cout, hidden, 3, 3]));
            if e.batch_norm {
                batch_norm(&mut t, &format!("{p}.4"), cout);
            }
        }
        let conv_out = widths.last().map_or(0, |w| w.2);
        t.push(("encoder.per_patch_linear.weight".into(), vec![e.token_dim, conv_out, 1, 1]));
        t.push(("encoder.per_patch_linear.bias".into(), vec![e.token_dim]));
        let inner = e.heads * e.dim_head;
        for l in 0..e.num_att_blocks {
            let p = format!("encoder.transformer.layers.{l}");
            layer_norm(&mut t, &format!("{p}.0.norm"), e.token_dim);
            linear(&mut t, &format!("{p}.0.fn.to_qkv"), 3 * inner, e.token_dim, false);
            linear(&mut t, &format!("{p}.0.fn.to_out.1"), e.token_dim, inner, true);
            layer_norm(&mut t, &format!("{p}.1.norm"), e.token_dim);
            linear(&mut t, &format!("{p}.1.fn.net.0"), e.ff_hidden, e.token_dim, true);
            linear(&mut t, &format!("{p}.1.fn.net.3"), e.token_dim, e.ff_hidden, true);
        }

        let q = self.query_dim();
        let inner = d.heads * d.dim_head;
        for l in 0..d.num_att_blocks {
            let p = format!("decoder_att.ray_predictor.transformer.layers.{l}");
            layer_norm(&mut t, &format!("{p}.0.norm"), q);
            linear(&mut t, &format!("{p}.0.fn.to_q"), inner, q, false);
            linear(&mut t, &format!("{p}.0.fn.to_kv"), 2 * inner, d.kv_dim, false);
            linear(&mut t, &format!("{p}.0.fn.to_out.1"), q, inner, true);
            layer_norm(&mut t, &format!("{p}.1.norm"), q);
            linear(&mut t, &format!("{p}.1.fn.net.0"), d.ff_hidden, q, true);
            linear(&mut t, &format!("{p}.1.fn.net.3"), q, d.ff_hidden, true);
        }
        linear(&mut t, "decoder_att.ray_predictor.input_mlp.0", d.input_mlp_hidden, q, true);
        linear(&mut t, "decoder_att.ray_predictor.input_mlp.2", q, d.input_mlp_hidden, true);
        let h = d.out_mlp_hidden;
        linear(&mut t, "decoder_att.out_mlp.0", h, q, true);
        for i in [2, 4, 6] {
            linear(&mut t, &format!("decoder_att.out_mlp.{i}"), h, h, true);
        }
        linear(&mut t, "decoder_att.out_mlp.8", d.out_dims, h, true);

        if let Some(rp) = &self.ray_patch {
            let p = "decoder_rp.conv_decoder";
            t.push((format!("{p}.conv_0.weight"), vec![rp.out_dims, rp.conv_features, 3, 3]));
            t.push((format!("{p}.conv_0.bias"), vec![rp.out_dims]));
            for i in 0..rp.upsample {
                let (cin, cout) = (rp.conv_features >> i, rp.conv_features >> (i + 1));
                let b = format!("{p}.conv_blocks.{i}");
                t.push((format!("{b}.0.1.weight"), vec![cout, cin, 3, 3]));
                t.push((format!("{b}.0.1.bias"), vec![cout]));
                if rp.batch_norm {
                    batch_norm(&mut t, &format!("{b}.0.2"), cout);
                }
                t.push((format!("{b}.1.weight"), vec![rp.out_dims, cout, 3, 3]));
                t.push((format!("{b}.1.bias"), vec![rp.out_dims]));
            }
        }
        t
    }
}
