//! The results: one [`Record`] per measured configuration, written as `results.json` and `results.csv`
//! (nested fields flattened to `a.b` columns), and the per-kernel GPU time breakdowns as `kernels.csv`.

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

/// Human-readable byte counts.
pub fn bytes(b: u64) -> String {
    let b = b as f64;
    if b >= (1u64 << 30) as f64 {
        format!("{:.2} GiB", b / (1u64 << 30) as f64)
    } else if b >= (1 << 20) as f64 {
        format!("{:.1} MiB", b / (1 << 20) as f64)
    } else {
        format!("{:.0} KiB", b / 1024.0)
    }
}

pub fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.digits$}"))
}

/// PyTorch's time over ours for the render and the encode (higher is better for us), where PyTorch ran, and
/// under torch.compile where that ran too.
fn speed_ratios(r: &Record) -> String {
    let over = |theirs: Option<Stats>, ours: Option<Stats>| theirs.zip(ours).map(|(t, o)| t.median_ms / o.median_ms);
    let encode = over(r.pytorch_encode_ms, r.encode_ms);
    let mut text = match (r.pytorch_over_ours, encode) {
        (None, None) => "-".into(),
        (render, encode) => format!("{}, {}", opt(render, 2), opt(encode, 2)),
    };
    let compiled =
        (over(r.pytorch_compiled_render_ms, r.render_wall_ms), over(r.pytorch_compiled_encode_ms, r.encode_ms));
    if compiled != (None, None) {
        text += &format!("; compiled {}, {}", opt(compiled.0, 2), opt(compiled.1, 2));
    }
    text
}

pub fn sci(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.1e}"))
}

fn stats_text(s: Option<Stats>) -> String {
    s.map_or_else(|| "-".into(), |s| format!("{:.2} [{:.2}–{:.2}]", s.median_ms, s.min_ms, s.max_ms))
}

/// The render's GPU time, where timestamps measured it (`-` where the wall clock is the only timing).
fn gpu_ms(r: &Record) -> Option<Stats> {
    r.render_gpu_ms
}

/// The host's time per render: wall minus GPU (medians), where timestamps measured the GPU.
pub fn host_ms(r: &Record) -> Option<f64> {
    Some(r.render_wall_ms?.median_ms - gpu_ms(r)?.median_ms)
}

/// Wall time, GPU time and the host's share (wall − GPU) of a render, side by side.
fn time_columns(r: &Record) -> [String; 3] {
    [stats_text(r.render_wall_ms), gpu_ms(r).map_or("-".into(), |g| format!("{:.2}", g.median_ms)), opt(host_ms(r), 2)]
}

/// A Markdown table of `rows` under `header`, and a blank line, appended to `out`.
pub fn table(out: &mut String, header: &[&str], rows: Vec<Vec<String>>) {
    *out += &format!("| {} |\n|{}\n", header.join(" | "), "---|".repeat(header.len()));
    for row in rows {
        *out += &format!("| {} |\n", row.join(" | "));
    }
    out.push('\n');
}

/// The results as Markdown tables (printed, and written to `tables.md` for docs/PERFORMANCE.md; the harness
/// appends the comparison with the paper after them).
pub fn markdown(records: &[Record], kernels: &[KernelTime], pytorch: &str) -> String {
    let mut out = String::new();
    if let Some(env) = records.iter().find_map(|r| r.env.as_ref()) {
        out += &format!(
            "Adapter: {} ({}, {}). Machine: {}. Matmul kernel: {}. Subgroup variants: {}. PyTorch: {pytorch}.\n\n",
            env.adapter,
            env.backend,
            env.driver,
            env.machine,
            env.matmul_kernel,
            if env.subgroups { "yes" } else { "no" }
        );
    }
    let timing = records.first().map_or("", |r| r.timing.as_str());
    out += &format!(
        "### Sweep (random weights; wall time per render call, median [min–max] ms; GPU time: {timing}; host = wall − GPU; fps from the GPU time)\n\n"
    );
    let sweep: Vec<&Record> = records.iter().filter(|r| r.group == "sweep").collect();
    table(
        &mut out,
        &[
            "model",
            "decoder",
            "k",
            "precision",
            "target",
            "wall ms",
            "GPU ms",
            "host ms",
            "fps",
            "encode ms",
            "render peak",
            "GFLOP render",
            "max err vs f64 ref",
            "vs f64 model",
            "vs PyTorch",
            "PyTorch / ours: render, encode",
        ],
        sweep
            .iter()
            .map(|r| {
                let mut row = vec![
                    r.model.clone(),
                    r.decoder.clone(),
                    r.k.to_string(),
                    r.precision.clone(),
                    format!("{}x{}", r.target_views, r.target_size),
                ];
                if r.render_wall_ms.is_some() {
                    row.extend(time_columns(r));
                } else {
                    row.extend([r.note.clone(), "-".into(), "-".into()]);
                }
                row.extend([
                    opt(r.fps, 2),
                    opt(r.encode_ms.map(|e| e.median_ms), 1),
                    r.render_peak_bytes.map_or("-".into(), bytes),
                    format!("{:.2}", r.render_gflop),
                    sci(r.max_err_f64_reference),
                    sci(r.max_err_f64_model),
                    sci(r.max_err_pytorch),
                    speed_ratios(r),
                ]);
                row
            })
            .collect(),
    );

    let accuracy = accuracy_rows(records);
    if !accuracy.is_empty() {
        out += "### Accuracy against the float64 model (max abs error: rgb / log-depth / mask; - where the model has no such output or it was not run)\n\n";
        table(
            &mut out,
            &[
                "model",
                "decoder",
                "k",
                "target",
                "f16-act, tensor kernels (Coop)",
                "f16-act, other kernels",
                "PyTorch bf16 autocast",
                "f32",
                "PyTorch f32",
            ],
            accuracy,
        );
    }

    let paths: Vec<&Record> = records.iter().filter(|r| r.group == "views").collect();
    if !paths.is_empty() {
        out += "### Several views: one batched call against a frame per view (`render-frame --view all`'s path: batches under the memory budget, each submitted before the last is read back); wall ms\n\n";
        let rows = paths
            .iter()
            .map(|p| {
                let batched = sweep.iter().find(|r| {
                    (&r.model, r.k, &r.precision, r.target_views, &r.target_size)
                        == (&p.model, p.k, &p.precision, p.target_views, &p.target_size)
                });
                let wall = |r: Option<&&Record>| r.and_then(|r| r.render_wall_ms).map(|w| w.median_ms);
                vec![
                    p.model.clone(),
                    p.decoder.clone(),
                    p.k.to_string(),
                    format!("{}x{}", p.target_views, p.target_size),
                    opt(wall(batched), 2),
                    batched.map_or("-".into(), |b| opt(gpu_ms(b).map(|g| g.median_ms), 2)),
                    stats_text(p.render_wall_ms),
                    opt(wall(Some(p)).zip(wall(batched)).map(|(p, b)| p / b), 2),
                    p.note.clone(),
                ]
            })
            .collect();
        table(
            &mut out,
            &[
                "model",
                "decoder",
                "k",
                "target",
                "batched wall ms",
                "batched GPU ms",
                "frame per view wall ms",
                "ratio",
                "note",
            ],
            rows,
        );
    }

    out += "### Ray-Patch speed-up over the per-pixel decoder (SRT or OSRT; fps ratio, same model and target size)\n\n";
    let mut rows = Vec::new();
    let mut keys: Vec<(String, String, String)> = Vec::new();
    // One target view per render (the paper's setting); renders of several views at once are in the sweep table.
    for r in sweep.iter().filter(|r| r.target_views == 1) {
        let key = (r.model.clone(), r.precision.clone(), r.target_size.clone());
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    for (model, precision, size) in keys {
        let fps = |k: usize| {
            sweep
                .iter()
                .find(|r| {
                    r.target_views == 1
                        && r.model == model
                        && r.precision == precision
                        && r.target_size == size
                        && r.k == k
                })
                .and_then(|r| r.fps)
        };
        let Some(srt) = fps(1) else { continue };
        let mut row = vec![model.clone(), precision.clone(), size.clone(), format!("{srt:.2}")];
        row.extend([2, 4, 8, 16].iter().map(|&k| fps(k).map_or("-".into(), |f| format!("{:.1}x", f / srt))));
        rows.push(row);
    }
    table(&mut out, &["model", "precision", "target", "k=1 fps", "k=2", "k=4", "k=8", "k=16"], rows);

    out += "### Golden cases (errors against PyTorch float32, the float64 reference and the float64 model)\n\n";
    table(
        &mut out,
        &[
            "case",
            "decoder",
            "k",
            "target",
            "wall ms",
            "GPU ms",
            "host ms",
            "encode ms",
            "max err vs PyTorch",
            "vs f64 ref",
            "vs f64 model",
            "PSNR dB",
        ],
        records
            .iter()
            .filter(|r| r.group == "golden")
            .map(|r| {
                vec![
                    r.model.clone(),
                    r.decoder.clone(),
                    r.k.to_string(),
                    format!("{}x{}", r.target_views, r.target_size),
                    time_columns(r)[0].clone(),
                    time_columns(r)[1].clone(),
                    time_columns(r)[2].clone(),
                    opt(r.encode_ms.map(|e| e.median_ms), 2),
                    sci(r.max_err_pytorch),
                    sci(r.max_err_f64_reference),
                    sci(r.max_err_f64_model),
                    opt(r.psnr_db, 2),
                ]
            })
            .collect(),
    );

    let files: Vec<&Record> = records.iter().filter(|r| r.group == "model").collect();
    if !files.is_empty() {
        out += "### Model files (--model; PSNR against the scene's target images)\n\n";
        table(
            &mut out,
            &[
                "model",
                "decoder",
                "k",
                "target",
                "wall ms",
                "GPU ms",
                "host ms",
                "fps",
                "encode ms",
                "render peak",
                "max err vs f64 ref",
                "vs PyTorch",
                "PyTorch / ours: render, encode",
                "PSNR dB",
            ],
            files
                .iter()
                .map(|r| {
                    vec![
                        r.model.clone(),
                        r.decoder.clone(),
                        r.k.to_string(),
                        format!("{}x{}", r.target_views, r.target_size),
                        time_columns(r)[0].clone(),
                        time_columns(r)[1].clone(),
                        time_columns(r)[2].clone(),
                        opt(r.fps, 2),
                        opt(r.encode_ms.map(|e| e.median_ms), 1),
                        r.render_peak_bytes.map_or("-".into(), bytes),
                        sci(r.max_err_f64_reference),
                        sci(r.max_err_pytorch),
                        speed_ratios(r),
                        opt(r.psnr_db, 2),
                    ]
                })
                .collect(),
        );
    }

    out += "### Skips on and off (render time)\n\n";
    table(
        &mut out,
        &["model", "decoder", "k", "target", "variant", "queries", "dispatches", "timing", "render ms", "render peak"],
        records
            .iter()
            .filter(|r| r.group == "skips")
            .map(|r| {
                vec![
                    r.model.clone(),
                    r.decoder.clone(),
                    r.k.to_string(),
                    r.target_size.clone(),
                    r.variant.clone(),
                    r.queries.to_string(),
                    r.dispatches.map_or("-".into(), |d| d.to_string()),
                    r.timing.clone(),
                    stats_text(r.render_ms),
                    r.render_peak_bytes.map_or("-".into(), bytes),
                ]
            })
            .collect(),
    );

    let mut configs: Vec<&str> = kernels.iter().map(|k| k.config.as_str()).collect();
    configs.dedup();
    for config in configs {
        out += &format!("### Where the time goes: {config} (GPU timestamps between ops)\n\n");
        let rows: Vec<&KernelTime> = kernels.iter().filter(|k| k.config == config).collect();
        let family = rows
            .iter()
            .filter(|k| k.op == "*")
            .map(|k| format!("{} {:.0}%", k.kernel, 100.0 * k.share))
            .collect::<Vec<_>>();
        out += &format!("By kernel: {}.\n\n", family.join(", "));
        table(
            &mut out,
            &["op (layers folded)", "kernel", "dispatches", "ms", "share"],
            rows.iter()
                .filter(|k| k.op != "*")
                .take(12)
                .map(|k| {
                    vec![
                        format!("`{}`", k.op),
                        k.kernel.clone(),
                        k.dispatches.to_string(),
                        format!("{:.2}", k.ms),
                        format!("{:.1}%", 100.0 * k.share),
                    ]
                })
                .collect(),
        );
    }

    out
}

/// A record's errors against the float64 model as `rgb / log-depth / mask` (`-` for each it lacks).
fn error_triple(rgb: Option<f64>, logdepth: Option<f64>, mask: Option<f64>) -> String {
    if (rgb, logdepth, mask) == (None, None, None) {
        return "-".into();
    }
    format!("{} / {} / {}", sci(rgb), sci(logdepth), sci(mask))
}

/// The accuracy table's rows: per sweep configuration of one target view (model, decoder, k, size) that has an
/// f16-act record or PyTorch's autocast error, the errors against the float64 model of f16-act on the tensor
/// kernels (`Coop`) and on the other kernels (which, in brackets), PyTorch under bf16 autocast, the engine in
/// f32, and PyTorch in f32 (rgb). Where several records give a column (merged runs), the first with a value.
pub fn accuracy_rows(records: &[Record]) -> Vec<Vec<String>> {
    let sweep: Vec<&Record> = records.iter().filter(|r| r.group == "sweep" && r.target_views == 1).collect();
    let mut keys: Vec<(&str, &str, usize, &str)> = Vec::new();
    for r in &sweep {
        let key = (r.model.as_str(), r.decoder.as_str(), r.k, r.target_size.as_str());
        if (r.precision == "f16-act" || r.max_err_autocast_f64_model.is_some()) && !keys.contains(&key) {
            keys.push(key);
        }
    }
    keys.into_iter()
        .map(|(model, decoder, k, size)| {
            let of = |r: &&&Record| r.model == model && r.decoder == decoder && r.k == k && r.target_size == size;
            let own = |r: &Record| {
                error_triple(r.max_err_f64_model, r.max_err_logdepth_f64_model, r.max_err_segmentation_f64_model)
            };
            let measured = |r: &&&Record| r.max_err_f64_model.is_some();
            let coop =
                sweep.iter().filter(of).filter(measured).find(|r| r.precision == "f16-act" && r.kernel == "Coop");
            let other =
                sweep.iter().filter(of).filter(measured).find(|r| r.precision == "f16-act" && r.kernel != "Coop");
            let autocast = sweep.iter().filter(of).find(|r| r.max_err_autocast_f64_model.is_some());
            let f32 = sweep.iter().filter(of).filter(measured).find(|r| r.precision == "f32");
            let torch = sweep.iter().filter(of).find_map(|r| r.max_err_pytorch_f64_model);
            let kernel = |r: &Record| if r.kernel.is_empty() { String::new() } else { format!(" ({})", r.kernel) };
            vec![
                model.to_string(),
                decoder.to_string(),
                k.to_string(),
                size.to_string(),
                coop.map_or("-".into(), |r| own(r)),
                other.map_or("-".into(), |r| own(r) + &kernel(r)),
                autocast.map_or("-".into(), |r| {
                    error_triple(
                        r.max_err_autocast_f64_model,
                        r.max_err_autocast_logdepth_f64_model,
                        r.max_err_autocast_segmentation_f64_model,
                    )
                }),
                f32.map_or("-".into(), |r| own(r)),
                sci(torch),
            ]
        })
        .collect()
}

/// When the run started, for the progress lines.
pub fn started() -> std::time::Instant {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    *START.get_or_init(std::time::Instant::now)
}

/// The progress line of a measured configuration: the engine's figures, then its render's wall time and
/// PyTorch's where measured (so that a log cut short still holds every comparison made).
pub fn print_row(r: &Record) {
    let ms = |s: Option<Stats>| s.map_or("-".to_string(), |s| format!("{:.2}", s.median_ms));
    let mut compared = String::new();
    if let Some(wall) = r.render_wall_ms {
        compared += &format!("; wall {:.2} ms", wall.median_ms);
    }
    if let Some(host) = host_ms(r) {
        compared += &format!(" (host {host:.2} ms)");
    }
    if let Some(buffers) = r.render_buffers_per_run.filter(|b| *b > 0.0) {
        compared += &format!("; {buffers:.1} buffers allocated per render");
    }
    if r.pytorch_render_ms.is_some() || r.pytorch_compiled_render_ms.is_some() {
        compared += &format!(
            "; PyTorch render {} ms (compiled {}), encode {} ms (compiled {})",
            ms(r.pytorch_render_ms),
            ms(r.pytorch_compiled_render_ms),
            ms(r.pytorch_encode_ms),
            ms(r.pytorch_compiled_encode_ms)
        );
    }
    println!(
        "  [{:>5.0} s] {:<12} {:<7} k={:<2} {} {:>2}x{:>9} {:<32} render {:>9.2} ms ({:>8.1} fps), encode {:>8.1} ms, peak {:>9}, err {}{}{compared}",
        started().elapsed().as_secs_f64(),
        r.model,
        r.decoder,
        r.k,
        r.precision,
        r.target_views,
        r.target_size,
        r.variant,
        r.render_ms.map_or(0.0, |s| s.median_ms),
        r.fps.unwrap_or(0.0),
        r.encode_ms.map_or(0.0, |e| e.median_ms),
        r.render_peak_bytes.map_or("-".into(), bytes),
        sci(r.max_err_f64_reference),
        error_vs_model(r),
    );
}

/// The progress line's errors against the float64 model (rgb, and log-depth and mask where measured).
fn error_vs_model(r: &Record) -> String {
    let mut text = String::new();
    if let Some(e) = r.max_err_f64_model {
        text += &format!(" (vs f64 model {e:.1e}");
        for (name, e) in [("log-depth", r.max_err_logdepth_f64_model), ("mask", r.max_err_segmentation_f64_model)] {
            if let Some(e) = e {
                text += &format!(", {name} {e:.1e}");
            }
        }
        text += ")";
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(model: &str, k: usize, precision: &str, kernel: &str) -> Record {
        Record {
            group: "sweep".into(),
            model: model.into(),
            decoder: if k == 1 { "OSRT".into() } else { "RP-OSRT".into() },
            k,
            precision: precision.into(),
            kernel: kernel.into(),
            target_views: 1,
            target_size: "24x32".into(),
            ..Default::default()
        }
    }

    #[test]
    fn accuracy_rows_put_each_precision_and_kernel_in_its_column() {
        let mut f32 = record("official-osrt", 1, "f32", "Lanes");
        (f32.max_err_f64_model, f32.max_err_segmentation_f64_model) = (Some(3e-4), Some(1e-5));
        (f32.max_err_autocast_f64_model, f32.max_err_autocast_segmentation_f64_model) = (Some(2.6e-2), Some(4e-3));
        f32.max_err_pytorch_f64_model = Some(3.1e-4);
        let mut coop = record("official-osrt", 1, "f16-act", "Coop");
        (coop.max_err_f64_model, coop.max_err_segmentation_f64_model) = (Some(2e-3), Some(5e-4));
        let mut lanes = record("official-osrt", 1, "f16-act", "Lanes");
        lanes.max_err_f64_model = Some(1.5e-3);
        // Not in the table: no f16-act and no autocast (k=8), several views, another group.
        let mut plain = record("official-osrt", 8, "f32", "Lanes");
        plain.max_err_f64_model = Some(1e-3);
        let views = Record { target_views: 8, ..coop.clone() };
        let golden = Record { group: "golden".into(), ..coop.clone() };
        let rows = accuracy_rows(&[f32, coop, lanes, plain, views, golden]);
        assert_eq!(
            rows,
            vec![vec![
                "official-osrt".to_string(),
                "OSRT".into(),
                "1".into(),
                "24x32".into(),
                "2.0e-3 / - / 5.0e-4".into(),
                "1.5e-3 / - / - (Lanes)".into(),
                "2.6e-2 / - / 4.0e-3".into(),
                "3.0e-4 / - / 1.0e-5".into(),
                "3.1e-4".into(),
            ]]
        );
        let tables = markdown(&rows_records(), &[], "torch");
        assert!(tables.contains("### Accuracy against the float64 model"), "{tables}");
        assert!(!markdown(&[], &[], "torch").contains("### Accuracy"));
    }

    fn rows_records() -> Vec<Record> {
        let mut r = record("official", 8, "f16-act", "Coop");
        r.max_err_f64_model = Some(1e-3);
        vec![r]
    }

    #[test]
    fn a_merged_record_without_an_f16_act_value_leaves_its_column_empty() {
        let unmeasured = record("official", 1, "f16-act", "Coop");
        let rows = accuracy_rows(&[unmeasured]);
        assert_eq!(rows[0][4..], ["-", "-", "-", "-", "-"]);
    }
}
