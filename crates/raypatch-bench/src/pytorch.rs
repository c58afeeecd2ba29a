//! The PyTorch reference timed on the same weights and inputs, through `tools/bench_pytorch.py`.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde::Deserialize;

use crate::measure::Stats;

/// The script, found from the source tree (the harness runs from a checkout).
pub fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/bench_pytorch.py")
}

/// The torch version when `python3` can import torch and safetensors, else why not.
pub fn probe() -> std::result::Result<String, String> {
    let out = Command::new("python3")
        .args(["-c", "import torch, safetensors; print(torch.__version__)"])
        .output()
        .map_err(|e| format!("python3 cannot be run: {e}"))?;
    if out.status.success() {
        Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
    } else {
        let err = String::from_utf8_lossy(&out.stderr);
        Err(format!("PyTorch cannot be imported ({})", err.lines().last().unwrap_or("").trim()))
    }
}

#[derive(Debug, Deserialize)]
struct TimesJson {
    median_ms: f64,
    min_ms: f64,
    max_ms: f64,
    runs: usize,
}

impl From<TimesJson> for Stats {
    fn from(t: TimesJson) -> Stats {
        Stats { median_ms: t.median_ms, min_ms: t.min_ms, max_ms: t.max_ms, runs: t.runs }
    }
}

#[derive(Debug, Deserialize)]
struct RunJson {
    threads: usize,
    encode: TimesJson,
    render: TimesJson,
}

/// PyTorch's times and output on one model and scene.
pub struct TorchRun {
    pub threads: usize,
    pub encode: Stats,
    pub render: Stats,
    /// `[T, Ht, Wt, 3]`.
    pub rgb: Vec<f32>,
}

/// Runs the script on files `model` and `scene`, writing its rgb next to them.
pub fn run(model: &Path, scene: &Path, repeats: usize) -> Result<TorchRun> {
    let rgb_path = scene.with_extension("pytorch-rgb.safetensors");
    let out = Command::new("python3")
        .arg(script())
        .args(["--model".as_ref(), model.as_os_str(), "--scene".as_ref(), scene.as_os_str()])
        .args(["--repeats", &repeats.to_string(), "--out-rgb"])
        .arg(&rgb_path)
        .output()
        .context("running python3 tools/bench_pytorch.py")?;
    if !out.status.success() {
        bail!("tools/bench_pytorch.py failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let json: RunJson = serde_json::from_slice(&out.stdout).context("tools/bench_pytorch.py printed no result")?;
    let rgb = raypatch_model::TensorFile::open(&rgb_path)?.f32("rgb")?.data;
    std::fs::remove_file(&rgb_path).ok();
    Ok(TorchRun { threads: json.threads, encode: json.encode.into(), render: json.render.into(), rgb })
}
