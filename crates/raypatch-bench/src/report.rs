//! The results: one [`Record`] per measured configuration and the per-kernel GPU time breakdowns
//! ([`KernelTime`]), and how they are written: `results.json` and `results.csv` (nested fields flattened to
//! `a.b` columns), `kernels.csv`, each through a temporary file. The Markdown tables of them are in
//! `report/tables.rs`, the progress line printed per configuration in `report/progress.rs`.

pub mod progress;
pub mod tables;

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::measure::Stats;

/// Where the numbers were measured; repeated in every record.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Environment {
    pub adapter: String,
    pub backend: String,
    pub driver: String,
    pub machine: String,
    /// The kernel of the linear layers (`Rows`, `Lanes`); absent in results from before it had a choice.
    #[serde(default = "rows_kernel")]
    pub matmul_kernel: String,
    /// Whether kernels with a subgroup variant used it (`device::KernelChoice::subgroups`); absent (false) in
    /// results from before there was one.
    #[serde(default)]
    pub subgroups: bool,
}

fn rows_kernel() -> String {
    "Rows".to_string()
}

/// One measured configuration.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Record {
    /// `golden` (assets/golden), `sweep` (random-weight models), `skips`, `model` (a file given with --model).
    pub group: String,
    /// `small` (random, the golden cases' structure at width 32), `official` (random, official MSN-Easy
    /// SRT / RP-SRT size), `official-osrt` (random, the official MSN-Easy OSRT / RP-OSRT k=8 runs), a golden
    /// case's name, or a model file.
    pub model: String,
    /// `SRT`, `RP-SRT`, `OSRT` or `RP-OSRT`.
    pub decoder: String,
    pub k: usize,
    /// `f32`; `f16`: f16 linear weights, f32 arithmetic; `f16-act`: f16 weights and every GEMM's operands
    /// rounded to f16 as they are staged, the sums in f32: on the tensor kernels (`Coop`) where the device has
    /// cooperative matrices, else on `Tiled`, and elsewhere as `f16` (`Precision`).
    pub precision: String,
    /// The kernel family the model's plans record their GEMMs on at this precision (`MatmulKernel`: `Coop`,
    /// the tensor kernels; `Tiled`, `Lanes`, `Rows`; ops whose shape suits another family still run there).
    /// Empty in results from before it was recorded.
    #[serde(default)]
    pub kernel: String,
    /// For the skips group: what is skipped or not.
    pub variant: String,
    pub parameters: usize,
    pub weight_bytes: u64,
    pub input_views: usize,
    pub input_size: String,
    pub target_views: usize,
    pub target_size: String,
    pub pixels: usize,
    /// Decoder queries per render (one per pixel for SRT and OSRT, per k×k patch for Ray-Patch).
    pub queries: usize,
    /// Kernel dispatches per render.
    pub dispatches: Option<usize>,
    /// Latent tokens (rows of the encoded latent: SRT's set-latent tokens, OSRT's slots).
    pub tokens: usize,
    /// `gpu timestamps` (GPU time of the plan's pass) or `wall clock`.
    pub timing: String,
    pub encode_ms: Option<Stats>,
    pub encode_wall_ms: Option<Stats>,
    /// The first render: builds the plan and compiles what it needs.
    pub first_render_wall_ms: Option<f64>,
    /// Pipelines the first render compiled: none where earlier shapes of the model compiled what it needs.
    #[serde(default)]
    pub first_render_pipelines: Option<u64>,
    /// Parsing the model file and loading it on the GPU, and the model's first encode (its pipelines
    /// compiled): with `first_render_wall_ms`, the first frame of a process. Absent where not measured.
    #[serde(default)]
    pub load_wall_ms: Option<f64>,
    #[serde(default)]
    pub first_encode_wall_ms: Option<f64>,
    pub render_ms: Option<Stats>,
    /// Host to host: uploads the target cameras, runs the plan, reads the image back.
    pub render_wall_ms: Option<Stats>,
    /// The render's GPU time (timestamps around its plan), where measured: `render_ms` is this, else the wall
    /// time. Absent in results from before it was kept apart.
    #[serde(default)]
    pub render_gpu_ms: Option<Stats>,
    /// Buffers and bytes the engine allocated per render after the first (staging buffers included): 0 when
    /// everything lives with the cached plan. Absent in results from before they were counted.
    #[serde(default)]
    pub render_buffers_per_run: Option<f64>,
    #[serde(default)]
    pub render_bytes_per_run: Option<f64>,
    /// Bytes of a render's staging buffers (inputs and outputs on their way to and from the GPU), kept with
    /// its plan beside `render_peak_bytes`.
    #[serde(default)]
    pub render_staging_bytes: Option<u64>,
    /// Frames per second of one target view, from the median `render_ms`.
    pub fps: Option<f64>,
    pub encode_peak_bytes: Option<u64>,
    /// Planned peak bytes of the render plan (intermediates, inputs, outputs, params; weights and the
    /// scene's keys/values are counted in `weight_bytes` and not here).
    pub render_peak_bytes: Option<u64>,
    /// What a decoder that materialised its softmax would hold (the paper's Figure 2a quantity): queries x
    /// tokens x heads; for OSRT the allocation transformer's heads x queries x slots plus the mixing block's
    /// queries x slots.
    pub attention_scores_bytes: u64,
    /// FLOPs of the encode: two per multiply-add the engine counts from the encode plan's ops.
    pub encode_gflop: f64,
    /// FLOPs of one render of the record's request (a region's render counts its crop): from the render
    /// plans' ops, or for a size not rendered, from the ops its plan records.
    pub render_gflop: f64,
    /// max |rgb − reference| against the float64 CPU reference with the encoding arguments rounded to f32
    /// as torch float32 rounds them: the engine's arithmetic error.
    pub max_err_f64_reference: Option<f64>,
    pub rms_err_f64_reference: Option<f64>,
    /// max |rgb − reference| against the float64 model (float64 encoding arguments).
    pub max_err_f64_model: Option<f64>,
    /// max |log-depth − float64 model| where the model has log-depth (DeFiNe's depth head, a 4-channel SRT or
    /// OSRT), and max |segmentation − float64 model| (OSRT's slot weights per pixel, the mask): from a render of
    /// those outputs beside the timed one.
    #[serde(default)]
    pub max_err_logdepth_f64_model: Option<f64>,
    #[serde(default)]
    pub max_err_segmentation_f64_model: Option<f64>,
    /// max |rgb − PyTorch float32| (the golden files, or PyTorch run by this harness).
    pub max_err_pytorch: Option<f64>,
    /// PyTorch float32's own max |rgb − float64 model| on the same inputs.
    #[serde(default)]
    pub max_err_pytorch_f64_model: Option<f64>,
    /// PyTorch eager under `torch.autocast(device, dtype=torch.bfloat16)` (`--pytorch-autocast`, `--accuracy`)
    /// against the float64 model on the same inputs: rgb, log-depth and segmentation where the model has them.
    #[serde(default)]
    pub max_err_autocast_f64_model: Option<f64>,
    #[serde(default)]
    pub max_err_autocast_logdepth_f64_model: Option<f64>,
    #[serde(default)]
    pub max_err_autocast_segmentation_f64_model: Option<f64>,
    /// PSNR against the scene's ground truth.
    pub psnr_db: Option<f64>,
    pub pytorch_encode_ms: Option<Stats>,
    pub pytorch_render_ms: Option<Stats>,
    /// The same under torch.compile (`--pytorch-compile`).
    pub pytorch_compiled_encode_ms: Option<Stats>,
    pub pytorch_compiled_render_ms: Option<Stats>,
    /// The same eager under bf16 autocast (`--pytorch-autocast`).
    #[serde(default)]
    pub pytorch_autocast_encode_ms: Option<Stats>,
    #[serde(default)]
    pub pytorch_autocast_render_ms: Option<Stats>,
    /// PyTorch's median render wall time over ours.
    pub pytorch_over_ours: Option<f64>,
    pub note: String,
    #[serde(flatten)]
    pub env: Option<Environment>,
}

/// GPU time per kernel of one render, from timestamps between the ops.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct KernelTime {
    /// The configuration, e.g. `official RP-SRT k=8 120x160 f32`.
    pub config: String,
    /// The op's label with layer indices and query-chunk ranges folded (e.g.
    /// `decoder_att.ray_predictor.transformer.layers.*.0.fn.to_q`), or a kernel family.
    pub op: String,
    pub kernel: String,
    pub dispatches: usize,
    pub ms: f64,
    pub share: f64,
}

/// Flattens nested objects into `a.b` keys (arrays are not used by the records).
fn flatten(prefix: &str, value: &Value, out: &mut Vec<(String, Value)>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                flatten(&key, v, out);
            }
        }
        _ => out.push((prefix.to_string(), value.clone())),
    }
}

fn csv_field(value: &Value) -> String {
    let text = match value {
        Value::Null => String::new(),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    };
    if text.contains([',', '"', '\n']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text
    }
}

/// Writes `rows` (serialisable structs) as CSV, the columns in order of first appearance.
pub fn write_csv<T: Serialize>(path: &Path, rows: &[T]) -> Result<()> {
    let flat: Vec<Vec<(String, Value)>> = rows
        .iter()
        .map(|r| {
            let mut out = Vec::new();
            flatten("", &serde_json::to_value(r).expect("records serialise"), &mut out);
            out
        })
        .collect();
    let mut columns: Vec<String> = Vec::new();
    for row in &flat {
        for (k, _) in row {
            if !columns.contains(k) {
                columns.push(k.clone());
            }
        }
    }
    let mut text = columns.join(",") + "\n";
    for row in &flat {
        let fields: Vec<String> = columns
            .iter()
            .map(|c| row.iter().find(|(k, _)| k == c).map_or(String::new(), |(_, v)| csv_field(v)))
            .collect();
        text += &(fields.join(",") + "\n");
    }
    write_file(path, text.as_bytes())
}

/// Writes through a temporary file and a rename, so that no partial file is left behind.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("partial");
    let mut file = std::fs::File::create(&tmp).with_context(|| format!("{}: cannot create", tmp.display()))?;
    file.write_all(bytes).with_context(|| format!("{}: cannot write", tmp.display()))?;
    drop(file);
    std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot write", path.display()))
}
