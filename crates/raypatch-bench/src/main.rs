//! `raypatch-bench [--quick] --out DIR`: measures raypatch and writes results.json, results.csv,
//! kernels.csv, tables.md and PNG plots into DIR.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Parser;
use raypatch_bench::pytorch::{self, Device, Torch};
use raypatch_engine::{AdapterChoice, Gpu, GpuOptions, MatmulKernel, PipelineCacheDir, Precision};

#[derive(Parser)]
#[command(version, about = "Benchmark raypatch: run time against error, memory, FLOPs; JSON, CSV and plots")]
struct Args {
    /// The smoke-test subset: small models, a few sizes, one official-size configuration (< 2 min on lavapipe).
    #[arg(long)]
    quick: bool,
    /// Folder for results.json, results.csv, kernels.csv, tables.md and the plots.
    #[arg(long)]
    out: PathBuf,
    /// Use the first adapter whose name contains this text.
    #[arg(long)]
    adapter: Option<String>,
    /// Measured runs per configuration, after a warm-up (default 5, quick 3).
    #[arg(long)]
    repeats: Option<usize>,
    /// Stop repeating a configuration once its measured runs took this many seconds (at least one run is
    /// always made; default 30, quick 2): many runs of the fast configurations, few of the slow.
    #[arg(long, value_name = "S")]
    repeat_seconds: Option<f64>,
    /// Skip sizes whose render is predicted to take longer than this many seconds (default 120, quick 1.5).
    #[arg(long)]
    max_render_seconds: Option<f64>,
    /// Compare with the float64 CPU reference only encodes and renders of at most this many billion
    /// multiply-adds (default 60, quick 2; the reference runs in float64 on the CPU, which takes minutes at
    /// the default).
    #[arg(long, value_name = "GMAC")]
    max_reference_gmac: Option<f64>,
    /// The kernel of the linear layers (default: the adapter's fastest).
    #[arg(long, value_name = "KERNEL", value_parser = PossibleValuesParser::new(MatmulKernel::ALL.map(MatmulKernel::name))
        .map(|name: String| MatmulKernel::from_name(&name).unwrap_or_default()))]
    matmul_kernel: Option<MatmulKernel>,
    /// Leave the adapter's subgroup operations unused: kernels run their variants without them (flash attention
    /// a query row per invocation; no `lanes` kernel), to compare the two.
    #[arg(long)]
    no_subgroups: bool,
    /// Make the target cameras' rays on the host and upload them, as on a GPU that does not make them bit-equal
    /// to the host's, to compare the two (by default a render makes a pinhole camera's rays on the GPU).
    #[arg(long)]
    rays_on_host: bool,
    /// Do not time PyTorch even if it is installed.
    #[arg(long)]
    no_pytorch: bool,
    /// Where PyTorch runs (default: on the CUDA GPU when the engine's adapter is a GPU and PyTorch has CUDA,
    /// else on the CPU).
    #[arg(long, value_name = "DEVICE", value_parser = PossibleValuesParser::new(Device::NAMES)
        .map(|name: String| Device::from_name(&name).unwrap_or(Device::Cpu)))]
    pytorch_device: Option<Device>,
    /// Time PyTorch under torch.compile too (beside eager), where it compiles.
    #[arg(long)]
    pytorch_compile: bool,
    /// Run PyTorch eager under torch.autocast with bfloat16 too (its time, and its error against the float64
    /// model where that is computed).
    #[arg(long)]
    pytorch_autocast: bool,
    /// Measure every sweep model at exactly these precisions (comma-separated: f32, f16, f16-act; default: f32,
    /// and f16 for SRT). f16-act runs every GEMM on the tensor kernels (cooperative matrices) where the device has
    /// them, else on the adapter's other kernels.
    #[arg(long = "precision", value_name = "P,...", value_delimiter = ',',
        value_parser = PossibleValuesParser::new(Precision::ALL.map(Precision::name))
            .map(|name: String| Precision::from_name(&name).unwrap_or_default()))]
    precisions: Vec<Precision>,
    /// Leave the tensor kernels (cooperative matrices) unused: f16-act then runs on the adapter's other kernels,
    /// as on a device without them.
    #[arg(long)]
    no_coop: bool,
    /// The accuracy run: each official family (SRT, RP-SRT k=8, OSRT, RP-OSRT k=8, DeFiNe, RP-DeFiNe k=16) at a
    /// small target size, rgb, log-depth and segmentation against the float64 model, PyTorch float32 and bf16
    /// autocast on the same inputs; one timed run. With --precision (default: the sweep's), --only, --no-pytorch.
    #[arg(long)]
    accuracy: bool,
    /// A model file to measure too (repeatable), e.g. a trained model.
    #[arg(long = "model")]
    models: Vec<PathBuf>,
    /// The scene for --model files (default: a synthetic 120x160 scene).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Measure only the sweep's random-weight model GROUP with patch size K, at every size; repeatable.
    /// GROUP small or official (SRT, K = 1, or RP-SRT, K = 2, 4, 8, 16), or official-osrt (the official
    /// OSRT, K = 1, or RP-OSRT, K = 8, at 120x160), or official-define (the official DeFiNe, K = 1, or RP-DeFiNe,
    /// K = 16, from two 128x192 views at 480x640 and 960x1280). Skips the golden cases. Merge into a full run with --replot.
    #[arg(long, value_name = "GROUP:K", value_parser = parse_only)]
    only: Vec<(String, usize)>,
    /// Measure only these target sizes of the sweep (comma-separated HxW, e.g. 120x160,480x640; default: every
    /// size of each model's sweep).
    #[arg(long, value_name = "HxW,...", value_delimiter = ',', value_parser = parse_size)]
    sizes: Vec<(usize, usize)>,
    /// Also render T target views at once at each measured sweep size (comma-separated counts, 2 to 256): a
    /// measurement per count, its frames per second counting views, PyTorch rendering as many at once
    #[arg(long, value_name = "T,...", value_delimiter = ',', value_parser = clap::value_parser!(u16).range(2..=256))]
    views: Vec<u16>,
    /// Measure only the hot linear layers of the official RP-SRT alone, on every matmul kernel the adapter
    /// runs (or the --matmul-kernel one) and in PyTorch: gemm.json and gemm.md in --out.
    #[arg(long)]
    gemm: bool,
    /// Time the WGSL GEMM kernels in this folder (tools/bench/gemm_lab.py writes it) on --gemm's shapes, with a
    /// sampled float64 check: gemm-lab.md in --out
    #[arg(long, value_name = "DIR")]
    gemm_lab: Option<PathBuf>,
    /// With --gemm-lab: only the kernels whose names contain one of these (comma-separated)
    #[arg(long, value_name = "NAME,...", value_delimiter = ',', requires = "gemm_lab")]
    lab_only: Vec<String>,
    /// Tune the tensor kernels' GEMM (f16 cooperative matrices, the f16-act precision's) on this adapter: time
    /// every workgroup tiling that fits on the official models' GEMM shapes of each class (small: at most 2048
    /// rows, large: more), keep the fastest per class in the engine's tuning file (raypatch's cache folder's
    /// coop-tuning.tsv, or --tuning-file; this adapter's lines replaced), then time 4096^3: coop-tune.md and
    /// coop-tune.json in --out. With --quick: small stand-in shapes and 512^3 (for CPU adapters).
    #[arg(long)]
    coop_tune: bool,
    /// With --coop-tune: the tuning file to write [default: coop-tuning.tsv in $RAYPATCH_CACHE_DIR, else
    /// $XDG_CACHE_HOME/raypatch, else ~/.cache/raypatch: where the engine reads it].
    #[arg(long, value_name = "FILE", requires = "coop_tune")]
    tuning_file: Option<PathBuf>,
    /// With --coop-tune: try no new tiling once this many seconds have passed (those tried decide).
    #[arg(long, value_name = "S", requires = "coop_tune")]
    tune_seconds: Option<f64>,
    /// Measure nothing: write tables.md and the plots into --out again from this results.json. Repeatable:
    /// later files' configurations replace earlier ones' (and the merged results are written too).
    #[arg(long, value_name = "RESULTS_JSON")]
    replot: Vec<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    if args.repeats == Some(0) {
        eprintln!("raypatch-bench: --repeats must be at least 1");
        return ExitCode::from(2);
    }
    if args.repeat_seconds.is_some_and(|s| !(s.is_finite() && s > 0.0)) {
        eprintln!("raypatch-bench: --repeat-seconds must be a number above 0");
        return ExitCode::from(2);
    }
    if args.max_reference_gmac.is_some_and(|g| g.is_nan() || g < 0.0) {
        eprintln!("raypatch-bench: --max-reference-gmac must be a number of at least 0");
        return ExitCode::from(2);
    }
    if !args.replot.is_empty() {
        return match raypatch_bench::replot(&args.replot, &args.out) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("raypatch-bench: {e:#}");
                ExitCode::from(2)
            }
        };
    }
    if args.tune_seconds.is_some_and(|s| !(s.is_finite() && s > 0.0)) {
        eprintln!("raypatch-bench: --tune-seconds must be a number above 0");
        return ExitCode::from(2);
    }
    if args.gemm || args.gemm_lab.is_some() || args.coop_tune {
        return match gemm(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("raypatch-bench: {e:#}");
                ExitCode::from(2)
            }
        };
    }
    let options = raypatch_bench::Options {
        quick: args.quick,
        out: args.out,
        adapter: args.adapter,
        matmul: args.matmul_kernel,
        without_subgroups: args.no_subgroups,
        rays_on_host: args.rays_on_host,
        repeats: args.repeats,
        repeat_seconds: args.repeat_seconds,
        max_render_seconds: args.max_render_seconds,
        max_reference_gmac: args.max_reference_gmac,
        pytorch: !args.no_pytorch,
        pytorch_device: args.pytorch_device,
        pytorch_compile: args.pytorch_compile,
        pytorch_autocast: args.pytorch_autocast,
        precisions: args.precisions,
        no_coop: args.no_coop,
        accuracy: args.accuracy,
        models: args.models,
        scene: args.scene,
        only: args.only,
        sizes: args.sizes,
        views: args.views.into_iter().map(usize::from).collect(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
    };
    match raypatch_bench::run(&options) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("raypatch-bench: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn gemm(args: &Args) -> anyhow::Result<()> {
    use anyhow::Context;
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}: cannot create", args.out.display()))?;
    let adapter = args.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
    if args.coop_tune {
        // The tuner's hundreds of pipelines stay out of the pipeline cache on disk.
        let gpu = Gpu::new(&GpuOptions { adapter, pipeline_cache: PipelineCacheDir::Off, ..Default::default() })?;
        let tuning_file = match &args.tuning_file {
            Some(file) => file.clone(),
            None => PipelineCacheDir::Auto
                .resolve()
                .map_err(|why| anyhow::anyhow!("no cache folder for the tuning file ({why}): give --tuning-file"))?
                .join(raypatch_engine::device::COOP_TUNING_FILE),
        };
        let options = raypatch_bench::coop_tune::TuneOptions {
            quick: args.quick,
            budget: args.tune_seconds.map(std::time::Duration::from_secs_f64),
            tuning_file: &tuning_file,
            out: &args.out,
        };
        let report = raypatch_bench::coop_tune::run(&gpu, &options)?;
        println!("\n{}", raypatch_bench::coop_tune::markdown(&report));
        return Ok(());
    }
    let gpu = Gpu::new(&GpuOptions { adapter, ..Default::default() })?;
    if let Some(dir) = &args.gemm_lab {
        println!("raypatch-bench --gemm-lab {} on {}", dir.display(), gpu.describe());
        let table = raypatch_bench::gemm_lab::run(&gpu, dir, &args.lab_only)?;
        raypatch_bench::report::write_file(&args.out.join("gemm-lab.md"), table.as_bytes())?;
        println!("\n{table}");
        return Ok(());
    }
    println!("raypatch-bench --gemm on {}", gpu.describe());
    let on_gpu = gpu.info.device_type != wgpu::DeviceType::Cpu;
    // Probed only when wanted: importing torch takes seconds.
    let installed = if args.no_pytorch { None } else { pytorch::probe().ok() };
    let torch = installed.map(|i| Torch::choose(i, args.pytorch_device, on_gpu, false)).transpose()?;
    let table =
        raypatch_bench::gemm::run(&gpu, args.matmul_kernel, torch.as_ref(), args.repeats.unwrap_or(10), &args.out)?;
    println!("\n{table}");
    Ok(())
}

fn parse_only(text: &str) -> Result<(String, usize), String> {
    let (group, k) = text.split_once(':').ok_or("expected GROUP:K, e.g. small:2 or official-osrt:8")?;
    let ks: &[usize] = match group {
        "small" | "official" => &[1, 2, 4, 8, 16],
        // The official OSRT runs: osrt_MDBN_64 and rposrt_MDBN_8_64.
        "official-osrt" => &[1, 8],
        // The official ScanNet runs: define_32_stereo_acc and rpdefine_16_32_stereo_acc.
        "official-define" => &[1, 16],
        _ => return Err(format!("group {group:?}: expected small, official, official-osrt or official-define")),
    };
    let expected = ks.iter().map(usize::to_string).collect::<Vec<_>>().join(", ");
    let k: usize = k.parse().map_err(|_| format!("k {k:?}: expected one of {expected} for {group}"))?;
    if !ks.contains(&k) {
        return Err(format!("k {k}: expected one of {expected} for {group}"));
    }
    Ok((group.to_string(), k))
}

/// A target size, `HxW` (height by width, in pixels, each at least 1).
fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let size = text.split_once('x').and_then(|(h, w)| Some((h.parse().ok()?, w.parse().ok()?)));
    size.filter(|&(h, w)| h > 0 && w > 0).ok_or_else(|| format!("{text:?}: expected HxW, e.g. 480x640"))
}

#[cfg(test)]
mod tests {
    use super::{parse_only, parse_size};

    #[test]
    fn sizes() {
        assert_eq!(parse_size("480x640"), Ok((480, 640)));
        assert!(parse_size("480").is_err());
        assert!(parse_size("0x640").is_err());
        assert!(parse_size("480x").is_err());
        assert!(parse_size("480x640x3").is_err());
    }

    #[test]
    fn only_selectors() {
        assert_eq!(parse_only("official:8"), Ok(("official".into(), 8)));
        assert_eq!(parse_only("official-osrt:1"), Ok(("official-osrt".into(), 1)));
        assert_eq!(parse_only("official-osrt:8"), Ok(("official-osrt".into(), 8)));
        assert!(parse_only("official-osrt:4").is_err());
        assert_eq!(parse_only("official-define:16"), Ok(("official-define".into(), 16)));
        assert!(parse_only("official-define:8").is_err());
        assert!(parse_only("osrt:8").is_err());
        assert!(parse_only("small:3").is_err());
        assert!(parse_only("small").is_err());
    }
}
