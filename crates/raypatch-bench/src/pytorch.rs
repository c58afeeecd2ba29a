//! The PyTorch reference timed on the same weights and inputs, through `tools/bench/bench_pytorch.py`: on the CPU,
//! or on a CUDA GPU when the engine runs on a GPU too (eager float32, and `torch.compile` when asked).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde::Deserialize;

use crate::measure::Stats;

/// Where PyTorch runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Device {
    Cpu,
    Cuda,
}

impl Device {
    pub const NAMES: [&'static str; 2] = ["cpu", "cuda"];

    pub fn name(self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            Device::Cuda => "cuda",
        }
    }

    pub fn from_name(name: &str) -> Option<Device> {
        match name {
            "cpu" => Some(Device::Cpu),
            "cuda" => Some(Device::Cuda),
            _ => None,
        }
    }
}

/// A file of the source tree: where the harness was built, or, for a binary carried to another machine and
/// run from a checkout there, relative to the current folder.
pub fn source_file(relative: &str) -> PathBuf {
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(relative);
    if built.exists() {
        built
    } else {
        PathBuf::from(relative)
    }
}

/// PyTorch as this machine has it.
#[derive(Clone, Debug)]
pub struct Installed {
    pub version: String,
    /// The name of CUDA device 0, when PyTorch has one.
    pub cuda: Option<String>,
}

/// What `python3` can import, or why PyTorch cannot be timed.
pub fn probe() -> std::result::Result<Installed, String> {
    let script = "import torch, safetensors\nprint(torch.__version__)\n\
                  print(torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')";
    let out =
        Command::new("python3").args(["-c", script]).output().map_err(|e| format!("python3 cannot be run: {e}"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        return Err(format!("PyTorch cannot be imported ({})", err.lines().last().unwrap_or("").trim()));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let mut lines = text.lines().map(str::trim);
    let version = lines.next().unwrap_or("").to_string();
    let cuda = lines.next().filter(|name| !name.is_empty()).map(str::to_string);
    Ok(Installed { version, cuda })
}

/// PyTorch as the harness times it.
#[derive(Clone, Debug)]
pub struct Torch {
    pub version: String,
    pub device: Device,
    /// "cpu", or the GPU's name.
    pub device_name: String,
    /// Time `torch.compile` too.
    pub compile: bool,
    /// Run the eager model once more under `torch.autocast(device, dtype=torch.bfloat16)` (PyTorch's mixed
    /// precision), timed, its outputs kept for their error against the float64 model.
    pub autocast: bool,
}

impl Torch {
    /// PyTorch on `device`, or where the engine runs (`None`): on the CUDA GPU when the engine's adapter is
    /// a GPU and PyTorch has one, else on the CPU. An explicit `cuda` that PyTorch lacks is an error.
    pub fn choose(installed: Installed, device: Option<Device>, engine_on_gpu: bool, compile: bool) -> Result<Torch> {
        let device = match (device, &installed.cuda) {
            (Some(Device::Cuda), None) => {
                bail!("--pytorch-device cuda: PyTorch {} has no CUDA device here", installed.version)
            }
            (Some(device), _) => device,
            (None, Some(_)) if engine_on_gpu => Device::Cuda,
            (None, _) => Device::Cpu,
        };
        let device_name = match device {
            Device::Cuda => installed.cuda.unwrap_or_default(),
            Device::Cpu => "cpu".to_string(),
        };
        Ok(Torch { version: installed.version, device, device_name, compile, autocast: false })
    }

    /// One line for the tables and results.json, e.g. `torch 2.5.1 on cuda (NVIDIA H100 80GB HBM3), eager and
    /// torch.compile`.
    pub fn describe(&self) -> String {
        let on = match self.device {
            Device::Cpu => "the CPU".to_string(),
            Device::Cuda => format!("cuda ({})", self.device_name),
        };
        let how = if self.compile { "eager and torch.compile" } else { "eager" };
        let autocast = if self.autocast { "; eager under bf16 autocast too" } else { "" };
        format!("torch {} on {on}, float32, {how}{autocast}", self.version)
    }

    /// The script's arguments for the device and compilation.
    fn args(&self) -> Vec<&'static str> {
        let mut args = vec!["--device", self.device.name()];
        if self.compile {
            args.push("--compile");
        }
        if self.autocast {
            args.push("--autocast-bf16");
        }
        args
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
struct PhasesJson {
    encode: TimesJson,
    render: TimesJson,
}

#[derive(Debug, Deserialize)]
struct RunJson {
    threads: usize,
    /// The vector ISA of PyTorch's CPU kernels (e.g. `AVX2`), where the script reports it.
    cpu_capability: Option<String>,
    #[serde(flatten)]
    eager: PhasesJson,
    compiled: Option<PhasesJson>,
    compile_error: Option<String>,
    /// The eager model under bf16 autocast (`--autocast-bf16`).
    autocast: Option<PhasesJson>,
}

/// Encode and render times of one way of running the model.
#[derive(Clone, Copy, Debug)]
pub struct Phases {
    pub encode: Stats,
    pub render: Stats,
}

impl From<PhasesJson> for Phases {
    fn from(p: PhasesJson) -> Phases {
        Phases { encode: p.encode.into(), render: p.render.into() }
    }
}

/// What one way of running the model rendered: `rgb` `[T, Ht, Wt, 3]`, and where the model returns them
/// `logdepth` `[T, Ht, Wt]` and OSRT's `segmentation` `[T, Ht, Wt, slots]`, as float32.
#[derive(Clone, Debug, Default)]
pub struct TorchOutputs {
    pub rgb: Vec<f32>,
    pub logdepth: Option<Vec<f32>>,
    pub segmentation: Option<Vec<f32>>,
}

impl TorchOutputs {
    /// The outputs the script wrote to `path` (rgb required, the others where present).
    fn read(path: &Path) -> Result<TorchOutputs> {
        let file = raypatch_model::TensorFile::open(path)?;
        let optional = |key: &str| -> Result<Option<Vec<f32>>> {
            Ok(if file.contains(key) { Some(file.f32(key)?.data) } else { None })
        };
        Ok(TorchOutputs {
            rgb: file.f32("rgb")?.data,
            logdepth: optional("logdepth")?,
            segmentation: optional("segmentation")?,
        })
    }
}

/// PyTorch's times and output on one model and scene.
pub struct TorchRun {
    pub threads: usize,
    pub cpu_capability: Option<String>,
    pub eager: Phases,
    /// Under torch.compile, when asked for and it ran; else why not (when asked for).
    pub compiled: std::result::Result<Option<Phases>, String>,
    /// Eager float32.
    pub outputs: TorchOutputs,
    /// Eager under bf16 autocast, when asked for ([`Torch::autocast`]): its times and outputs.
    pub autocast: Option<(Phases, TorchOutputs)>,
}

/// Runs the script on files `model` and `scene`, writing its outputs next to them (and reading them back).
pub fn run(torch: &Torch, model: &Path, scene: &Path, repeats: usize) -> Result<TorchRun> {
    let rgb_path = scene.with_extension("pytorch-rgb.safetensors");
    let autocast_path = scene.with_extension("pytorch-autocast.safetensors");
    let mut command = Command::new("python3");
    command
        .arg(source_file("tools/bench/bench_pytorch.py"))
        .args(["--model".as_ref(), model.as_os_str(), "--scene".as_ref(), scene.as_os_str()])
        .args(torch.args())
        .args(["--repeats", &repeats.to_string(), "--out-rgb"])
        .arg(&rgb_path);
    if torch.autocast {
        command.arg("--out-autocast").arg(&autocast_path);
    }
    let out = command.output().context("running python3 tools/bench/bench_pytorch.py")?;
    if !out.status.success() {
        bail!("tools/bench/bench_pytorch.py failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let json: RunJson =
        serde_json::from_slice(&out.stdout).context("tools/bench/bench_pytorch.py printed no result")?;
    let outputs = TorchOutputs::read(&rgb_path)?;
    std::fs::remove_file(&rgb_path).ok();
    let autocast = match json.autocast {
        Some(phases) if torch.autocast => {
            let outputs = TorchOutputs::read(&autocast_path)?;
            std::fs::remove_file(&autocast_path).ok();
            Some((phases.into(), outputs))
        }
        _ => None,
    };
    let compiled = match (json.compiled, json.compile_error) {
        (_, Some(why)) => Err(why),
        (compiled, None) => Ok(compiled.map(Phases::from)),
    };
    Ok(TorchRun {
        threads: json.threads,
        cpu_capability: json.cpu_capability,
        eager: json.eager.into(),
        compiled,
        outputs,
        autocast,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn installed(cuda: Option<&str>) -> Installed {
        Installed { version: "2.5.1".into(), cuda: cuda.map(str::to_string) }
    }

    #[test]
    fn device_follows_the_engine_unless_named() {
        let h100 = Some("NVIDIA H100");
        let on = |cuda, device, gpu| Torch::choose(installed(cuda), device, gpu, false).map(|t| t.device).ok();
        assert_eq!(on(h100, None, true), Some(Device::Cuda));
        assert_eq!(on(h100, None, false), Some(Device::Cpu));
        assert_eq!(on(None, None, true), Some(Device::Cpu));
        assert_eq!(on(h100, Some(Device::Cpu), true), Some(Device::Cpu));
        assert_eq!(on(h100, Some(Device::Cuda), false), Some(Device::Cuda));
        let err = Torch::choose(installed(None), Some(Device::Cuda), true, false).unwrap_err().to_string();
        assert!(err.contains("--pytorch-device cuda") && err.contains("no CUDA device"), "{err}");
    }

    #[test]
    fn description_names_the_device_and_compilation() {
        let torch = Torch::choose(installed(Some("NVIDIA H100")), None, true, true).unwrap();
        assert_eq!(torch.describe(), "torch 2.5.1 on cuda (NVIDIA H100), float32, eager and torch.compile");
        assert_eq!(torch.args(), ["--device", "cuda", "--compile"]);
        let cpu = Torch::choose(installed(None), None, true, false).unwrap();
        assert_eq!(cpu.describe(), "torch 2.5.1 on the CPU, float32, eager");
        let autocast = Torch { autocast: true, ..cpu };
        assert_eq!(autocast.describe(), "torch 2.5.1 on the CPU, float32, eager; eager under bf16 autocast too");
        assert_eq!(autocast.args(), ["--device", "cpu", "--autocast-bf16"]);
    }

    #[test]
    fn script_outputs_read_back_with_the_optional_ones() {
        let dir = std::env::temp_dir().join(format!("raypatch-bench-outputs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let tensor = |name: &str, values: &[f32], shape: Vec<usize>| -> crate::synthetic::Tensor {
            (name.into(), shape, values.to_vec())
        };
        let rgb = tensor("rgb", &[0.5; 6], vec![1, 1, 2, 3]);
        let with = crate::synthetic::serialize(
            &[rgb.clone(), tensor("logdepth", &[1.0, 2.0], vec![1, 1, 2])],
            Default::default(),
        )
        .unwrap();
        let path = dir.join("with.safetensors");
        std::fs::write(&path, with).unwrap();
        let read = TorchOutputs::read(&path).unwrap();
        assert_eq!((read.rgb.len(), read.logdepth, read.segmentation), (6, Some(vec![1.0, 2.0]), None));
        let without = crate::synthetic::serialize(&[rgb], Default::default()).unwrap();
        std::fs::write(&path, without).unwrap();
        let read = TorchOutputs::read(&path).unwrap();
        assert!(read.logdepth.is_none() && read.segmentation.is_none());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn script_output_with_and_without_compilation() {
        let times = r#"{"median_ms": 2.0, "min_ms": 1.0, "max_ms": 3.0, "runs": 3}"#;
        let eager = format!(r#""threads": 2, "device": "cpu", "encode": {times}, "render": {times}"#);
        let plain: RunJson = serde_json::from_str(&format!("{{{eager}}}")).unwrap();
        assert!(plain.compiled.is_none() && plain.compile_error.is_none());
        assert_eq!(plain.eager.render.median_ms, 2.0);
        let compiled: RunJson =
            serde_json::from_str(&format!(r#"{{{eager}, "compiled": {{"encode": {times}, "render": {times}}}}}"#))
                .unwrap();
        assert_eq!(compiled.compiled.unwrap().encode.runs, 3);
        let failed: RunJson = serde_json::from_str(&format!(r#"{{{eager}, "compile_error": "no compiler"}}"#)).unwrap();
        assert_eq!(failed.compile_error.as_deref(), Some("no compiler"));
        assert!(failed.autocast.is_none());
        let autocast: RunJson = serde_json::from_str(&format!(
            r#"{{{eager}, "autocast": {{"dtype": "bfloat16", "encode": {times}, "render": {times}}}}}"#
        ))
        .unwrap();
        assert_eq!(autocast.autocast.unwrap().render.median_ms, 2.0);
    }
}
