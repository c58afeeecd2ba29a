//! The model config: the official `config.yaml` model section (stored as JSON in the safetensors metadata),
//! resolved into every dimension the engine needs. The official `base` key names the family; each family's
//! config is one type in its own file ([`srt`], [`osrt`]), behind the [`Family`] enum. Absent keys take the official
//! constructors' defaults; the raypatch extension keys (docs/FORMATS.md) default to the widths the official
//! code hard-codes.

pub mod define;
pub mod osrt;
pub mod srt;

use serde_json::Value;

use crate::error::{ModelError, Quoted};
pub use define::{DefineConfig, DefineDecoderConfig, DefineEncoderConfig, RayFeatures};
pub use osrt::{OsrtConfig, SlotAttentionConfig, SlotMixerConfig};
pub use srt::{DecoderConfig, EncoderConfig, RayPatchConfig, RayPredictorConfig, SrtConfig};

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
/// Most layers of one kind (blocks, halvings): also checked against the tensors in the file.
pub const MAX_LAYERS: usize = 1024;
/// Most iterations of a loop over the same weights (slot attention's `slot_iters`): nothing in the file
/// bounds these, and each one adds its ops to the encoder plan.
pub const MAX_ITERATIONS: usize = 100;
/// Most Fourier octaves of one encoding.
pub const MAX_OCTAVES: usize = 32;
/// Longest image or patch-grid side a config may name (the API's largest image side).
pub const MAX_SIDE: usize = 16384;

/// What an integer config value counts, and so the most accepted. Every integer key is read with one
/// ([`Section::usize`]), so that no config value can make the engine build or run without bound.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Count {
    Width,
    Layers,
    Iterations,
    Octaves,
    Side,
}

impl Count {
    fn max(self) -> (usize, &'static str) {
        match self {
            Count::Width => (MAX_WIDTH, "a width"),
            Count::Layers => (MAX_LAYERS, "a layer count"),
            Count::Iterations => (MAX_ITERATIONS, "an iteration count"),
            Count::Octaves => (MAX_OCTAVES, "an octave count"),
            Count::Side => (MAX_SIDE, "an image side"),
        }
    }
}

/// A model's config: its family's resolved config, and the config as stored in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelConfig {
    pub family: Family,
    pub raw: Value,
}

/// The model families, named by the official `base` key.
#[derive(Clone, Debug, PartialEq)]
pub enum Family {
    /// `base: srt`: SRT (`decoder: lightfield`) and RP-SRT (`decoder: featurefield`).
    Srt(SrtConfig),
    /// `base: osrt`: OSRT (`decoder: lightfield`) and RP-OSRT (`decoder: featurefield`).
    Osrt(OsrtConfig),
    /// `base: define`: DeFiNe (`decoder: lightfield`) and RP-DeFiNe (`decoder: featurefield`).
    Define(DefineConfig),
}

impl Family {
    /// The family's config as what every part of raypatch asks of it.
    pub fn describe(&self) -> &dyn FamilyConfig {
        match self {
            Family::Srt(c) => c,
            Family::Osrt(c) => c,
            Family::Define(c) => c,
        }
    }
}

/// What every part of raypatch asks of a model family, answered once per family by its config type (the
/// family's file in `config/`): [`Family::describe`] is the one place that tells the families apart. The engine
/// builds each family's modules from its config type (`raypatch_engine::models::build`), the float64 reference
/// likewise; everything else (the CLI's labels, the bench, the checks) asks here.
pub trait FamilyConfig {
    /// The official `base` key's value: "srt", "osrt", "define".
    fn base(&self) -> &'static str;
    /// The family's name in the paper: "SRT", "OSRT", "DeFiNe" (its Ray-Patch variant is "RP-" + this).
    fn name(&self) -> &'static str;
    /// The Ray-Patch decoder's config, for Ray-Patch models.
    fn ray_patch(&self) -> Option<&RayPatchConfig>;
    /// Whether the model predicts a (log-)depth channel beside rgb.
    fn has_depth(&self) -> bool;
    /// What the model's rays are: unit directions or unit-depth points.
    fn ray_kind(&self) -> RayKind;
    /// The Fourier encodings of camera positions: of input views (encoder), of target views (decoder).
    fn position_octaves(&self) -> (&Octaves, &Octaves);
    /// `(config key, count)` of every layer count, each to be checked against the file's tensors.
    fn layer_counts(&self) -> Vec<(&'static str, usize)>;
    /// The heads of each attention a decoder query makes over the latent tokens (what a materialised softmax
    /// would hold per query and token).
    fn decoder_attention_heads(&self) -> Vec<usize>;
    /// Whether the official model's forward returns a depth map computed by a head of its own (DeFiNe), so
    /// that a like-for-like render asks for log-depth too.
    fn depth_has_own_head(&self) -> bool;
}

/// What a model's rays are: the per-pixel vectors of a scene's `input_rays` and `target_rays`, and what a
/// camera (intrinsics K, camera-to-world rotation R with OpenCV axes, centre c) is turned into for the model.
/// Both are taken through the pixel centres p = [u + 0.5, v + 0.5, 1] (u the column, v the row from the top),
/// in the world frame; they differ only in scale and origin.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RayKind {
    /// A unit direction normalize(R·K⁻¹p), independent of where the camera is (SRT and OSRT: the official
    /// MultiShapeNet loader's `get_camera_rays`).
    UnitDirection,
    /// The world point at unit depth along the camera's forward axis, c + R·K⁻¹p: not normalised, and not
    /// relative to the camera (DeFiNe: the official ScanNet loader's `T_world_camera · [K⁻¹p, 1]`). Its offset
    /// from the camera centre has length 1 only on the optical axis.
    UnitDepthPoint,
}

impl RayKind {
    /// The kind in messages: "unit ray directions", or "unit-depth points" with their formula.
    pub fn describe(self) -> &'static str {
        match self {
            RayKind::UnitDirection => "unit ray directions",
            RayKind::UnitDepthPoint => "unit-depth points (camera centre + R·K⁻¹[u+0.5, v+0.5, 1])",
        }
    }
}

/// The families raypatch runs, by their official `base`: the registration of a family (with its arm in
/// [`ModelConfig::from_value`]). `tests/golden.rs` checks that each has golden cases, plain and Ray-Patch.
pub const FAMILY_BASES: [&str; 3] = ["srt", "osrt", "define"];

/// [`FAMILY_BASES`] for messages.
fn bases() -> String {
    let quoted: Vec<String> = FAMILY_BASES.iter().map(|b| format!("\"{b}\"")).collect();
    quoted.join(", ")
}

impl ModelConfig {
    /// Resolves the model section of a run config. `path` names the file in errors.
    pub fn from_value(path: &str, raw: Value) -> Result<ModelConfig, ModelError> {
        if !raw.is_object() {
            return Err(config_err(path, format!("the model config must be a mapping, found {raw}")));
        }
        let family = match raw.get("base").and_then(Value::as_str) {
            Some("srt") => Family::Srt(SrtConfig::from_value(path, &raw)?),
            Some("osrt") => Family::Osrt(OsrtConfig::from_value(path, &raw)?),
            Some("define") => Family::Define(DefineConfig::from_value(path, &raw)?),
            Some(other) => {
                return Err(config_err(
                    path,
                    format!(
                        "model base `{other}` is not supported (raypatch runs {}: SRT, RP-SRT, OSRT, RP-OSRT, DeFiNe and RP-DeFiNe)",
                        bases()
                    ),
                ))
            }
            None => return Err(config_err(path, format!("missing `base` (expected one of {})", bases()))),
        };
        Ok(ModelConfig { family, raw })
    }

    /// The family's answers ([`FamilyConfig`]).
    pub fn describe(&self) -> &dyn FamilyConfig {
        self.family.describe()
    }

    /// The official `base` of this model.
    pub fn base(&self) -> &'static str {
        self.describe().base()
    }

    /// The model's name: the family's ("SRT", "OSRT", "DeFiNe"), "RP-" before it for Ray-Patch models.
    pub fn name(&self) -> String {
        let family = self.describe().name();
        if self.ray_patch().is_some() {
            format!("RP-{family}")
        } else {
            family.to_string()
        }
    }

    /// The model's name with its patch size for Ray-Patch models: "SRT", "RP-SRT k=8".
    pub fn label(&self) -> String {
        match self.ray_patch() {
            Some(rp) => format!("{} k={}", self.name(), rp.patch_size()),
            None => self.name(),
        }
    }

    /// The SRT config, for code that only runs SRT models.
    pub fn srt(&self) -> Option<&SrtConfig> {
        match &self.family {
            Family::Srt(c) => Some(c),
            Family::Osrt(_) | Family::Define(_) => None,
        }
    }

    /// Pixels per decoder query along each axis: 1 for per-pixel decoders, k for Ray-Patch.
    pub fn patch_size(&self) -> usize {
        self.ray_patch().map_or(1, RayPatchConfig::patch_size)
    }

    /// The Ray-Patch decoder's config, for Ray-Patch models.
    pub fn ray_patch(&self) -> Option<&RayPatchConfig> {
        self.describe().ray_patch()
    }

    /// Whether the decoder resizes its output to the target size (see [`RayPatchConfig::resize_out`]).
    pub fn resizes_output(&self) -> bool {
        self.ray_patch().is_some_and(|rp| rp.resize_out.is_some())
    }

    /// Whether the model predicts a log-depth channel beside rgb.
    pub fn has_depth(&self) -> bool {
        self.describe().has_depth()
    }

    /// What this model's rays are: unit directions (SRT, OSRT) or unit-depth points (DeFiNe).
    pub fn ray_kind(&self) -> RayKind {
        self.describe().ray_kind()
    }

    /// The Fourier encodings of camera positions: of input views (encoder), of target views (decoder).
    pub fn position_octaves(&self) -> (&Octaves, &Octaves) {
        self.describe().position_octaves()
    }

    /// Checks the config's layer counts against a file holding `tensors` tensors, before anything as large as
    /// a count is built: each layer has at least one tensor, so a count above the file's is a lie.
    pub fn check_counts(&self, path: &str, tensors: usize) -> Result<(), ModelError> {
        for (key, count) in self.describe().layer_counts() {
            if count > tensors {
                return Err(config_err(
                    path,
                    format!("`{key}` is {count}, but the file holds only {tensors} tensors (at least one per layer)"),
                ));
            }
        }
        Ok(())
    }
}

/// Reads typed keys out of one section, naming the section and key in errors.
pub(crate) struct Section<'a> {
    path: &'a str,
    name: &'a str,
    value: Option<&'a Value>,
}

impl<'a> Section<'a> {
    pub(crate) fn new(path: &'a str, root: &'a Value, name: &'a str) -> Result<Self, ModelError> {
        let value = root.get(name).filter(|v| !v.is_null());
        if let Some(v) = value {
            if !v.is_object() {
                return Err(config_err(path, format!("`{name}` must be a mapping, found {}", Quoted(v))));
            }
        }
        Ok(Section { path, name, value })
    }

    pub(crate) fn get(&self, key: &str) -> Option<&'a Value> {
        self.value.and_then(|v| v.get(key)).filter(|v| !v.is_null())
    }

    /// The integer `key` (or `default`), at most what `count` allows.
    pub(crate) fn usize(&self, key: &str, default: usize, count: Count) -> Result<usize, ModelError> {
        let Some(v) = self.get(key) else { return Ok(default) };
        let value = v.as_u64().ok_or_else(|| {
            config_err(self.path, format!("`{}.{key}` must be a non-negative integer, found {}", self.name, Quoted(v)))
        })?;
        let (max, what) = count.max();
        if value > max as u64 {
            return Err(config_err(
                self.path,
                format!("`{}.{key}` is {value}; at most {max} is supported ({what})", self.name),
            ));
        }
        Ok(value as usize)
    }

    pub(crate) fn f64(&self, key: &str, default: f64) -> Result<f64, ModelError> {
        self.opt_f64(key).map(|v| v.unwrap_or(default))
    }

    pub(crate) fn opt_f64(&self, key: &str) -> Result<Option<f64>, ModelError> {
        match self.get(key) {
            None => Ok(None),
            Some(v) => v.as_f64().map(Some).ok_or_else(|| {
                config_err(self.path, format!("`{}.{key}` must be a number, found {}", self.name, Quoted(v)))
            }),
        }
    }

    pub(crate) fn bool(&self, key: &str, default: bool) -> Result<bool, ModelError> {
        match self.get(key) {
            None => Ok(default),
            Some(v) => v.as_bool().ok_or_else(|| {
                config_err(self.path, format!("`{}.{key}` must be true or false, found {}", self.name, Quoted(v)))
            }),
        }
    }

    /// `norm: Batch` → true; absent or null → false; anything else is an error.
    pub(crate) fn batch_norm(&self) -> Result<bool, ModelError> {
        match self.get("norm") {
            None => Ok(false),
            Some(Value::String(s)) if s == "Batch" => Ok(true),
            Some(v) => Err(config_err(
                self.path,
                format!("`{}.norm` must be \"Batch\" or null, found {}", self.name, Quoted(v)),
            )),
        }
    }

    pub(crate) fn octaves(
        &self,
        count_key: &str,
        start_key: &str,
        end_key: &str,
        count: usize,
        start: f64,
    ) -> Result<Octaves, ModelError> {
        Ok(Octaves {
            count: self.usize(count_key, count, Count::Octaves)?,
            start: self.f64(start_key, start)?,
            end: self.opt_f64(end_key)?,
        })
    }
}

pub(crate) fn config_err(path: &str, reason: String) -> ModelError {
    ModelError::Config { path: path.to_string(), reason }
}

/// Checks a list of `(key, value)` config values: each must be positive.
pub(crate) fn check_positive(path: &str, values: &[(&str, usize)]) -> Result<(), ModelError> {
    match values.iter().find(|(_, v)| *v == 0) {
        Some((key, _)) => Err(config_err(path, format!("`{key}` must be positive"))),
        None => Ok(()),
    }
}

/// Checks layer widths against [`MAX_WIDTH`].
pub(crate) fn check_widths(path: &str, widths: &[(&str, usize)]) -> Result<(), ModelError> {
    match widths.iter().find(|(_, w)| *w > MAX_WIDTH) {
        Some((key, width)) => Err(config_err(path, format!("`{key}` is {width}; at most {MAX_WIDTH} is supported"))),
        None => Ok(()),
    }
}

/// Checks Fourier encodings: at most 32 octaves, multipliers in float32's normal range.
pub(crate) fn check_octaves(path: &str, encodings: &[(&str, &Octaves)]) -> Result<(), ModelError> {
    for (key, octaves) in encodings {
        if octaves.count > MAX_OCTAVES {
            return Err(config_err(
                path,
                format!("`{key}` is {}; at most {MAX_OCTAVES} octaves are supported", octaves.count),
            ));
        }
        if let Some(m) = octaves.multipliers_out_of_f32_range() {
            return Err(config_err(
                path,
                format!("`{key}` gives a Fourier multiplier of {m:e}, outside float32's normal range"),
            ));
        }
    }
    Ok(())
}
