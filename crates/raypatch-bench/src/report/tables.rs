//! The results as Markdown tables (`tables.md`, printed at the end of a run) and the cell formats they share
//! with the progress line and the paper comparison: byte counts, optional and scientific numbers, timings.

use super::{KernelTime, Record};
use crate::measure::Stats;

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

/// A row's first columns in the golden and model-file tables: model, decoder, k, target, then [`time_columns`].
fn identity_and_times(r: &Record) -> Vec<String> {
    let mut row =
        vec![r.model.clone(), r.decoder.clone(), r.k.to_string(), format!("{}x{}", r.target_views, r.target_size)];
    row.extend(time_columns(r));
    row
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
                let mut row = identity_and_times(r);
                row.extend([
                    opt(r.encode_ms.map(|e| e.median_ms), 2),
                    sci(r.max_err_pytorch),
                    sci(r.max_err_f64_reference),
                    sci(r.max_err_f64_model),
                    opt(r.psnr_db, 2),
                ]);
                row
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
                    let mut row = identity_and_times(r);
                    row.extend([
                        opt(r.fps, 2),
                        opt(r.encode_ms.map(|e| e.median_ms), 1),
                        r.render_peak_bytes.map_or("-".into(), bytes),
                        sci(r.max_err_f64_reference),
                        sci(r.max_err_pytorch),
                        speed_ratios(r),
                        opt(r.psnr_db, 2),
                    ]);
                    row
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
