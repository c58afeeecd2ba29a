//! The benchmark run: the options, the shared setup (`Bench`: GPU, repeats, PyTorch) and where the results go
//! (`results.json`, CSV, tables, plots, and `replot`). How one configuration is measured (encode, render timing,
//! errors against the references and PyTorch) is in `harness/measurement.rs`; which random-weight
//! configurations are swept in `harness/sweep.rs`; the golden cases and `--model` files in `harness/cases.rs`;
//! the skips on and off and the per-kernel breakdown in `harness/skips.rs`.

mod cases;
mod measurement;
mod replot;
mod skips;
mod sweep;

pub use replot::replot;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use raypatch_engine::gpu::TimestampMode;
use raypatch_engine::{AdapterChoice, Gpu, GpuOptions, MatmulKernel, Precision};
use raypatch_model::{InputViews, TargetViews};
use serde::{Deserialize, Serialize};

use crate::measure::{self, Repeats};
use crate::report::{self, Environment, KernelTime, Record};
use crate::synthetic::{self, CameraRig};
use crate::{paper, plots, pytorch};

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// The smoke-test subset (under 2 minutes on lavapipe).
    pub quick: bool,
    pub out: PathBuf,
    pub adapter: Option<String>,
    /// The matmul kernel to force (`None`: the adapter's fastest).
    pub matmul: Option<MatmulKernel>,
    /// Leave the adapter's subgroup operations unused (`GpuOptions::without_subgroups`).
    pub without_subgroups: bool,
    /// Make pinhole cameras' rays on the host and upload them (`GpuOptions::rays_on_host`).
    pub rays_on_host: bool,
    /// Measured runs per configuration (default 5, quick 3).
    pub repeats: Option<usize>,
    /// Stop repeating a configuration once its measured runs took this long, in seconds (default 30, quick 2).
    pub repeat_seconds: Option<f64>,
    /// Skip configurations whose render is predicted (from its multiply-adds, counted from the ops its plan
    /// would record, and the rate measured at the previous size) to take longer than this (default 120 s,
    /// quick 1.5 s).
    pub max_render_seconds: Option<f64>,
    /// Compute the float64 CPU references of encodes and renders of at most this many billion multiply-adds
    /// (default 60, quick 2): they take minutes beyond that.
    pub max_reference_gmac: Option<f64>,
    /// Time PyTorch on the same inputs when it is installed.
    pub pytorch: bool,
    /// Where PyTorch runs (`None`: on the CUDA GPU when the engine runs on a GPU and PyTorch has one).
    pub pytorch_device: Option<pytorch::Device>,
    /// Time PyTorch under torch.compile too.
    pub pytorch_compile: bool,
    /// Run PyTorch eager under bf16 autocast too, its error against the float64 model recorded.
    pub pytorch_autocast: bool,
    /// Measure every sweep model at exactly these precisions (empty: the sweep's own choice: f32, and f16 for
    /// SRT where the adapter has shader-f16).
    pub precisions: Vec<Precision>,
    /// Leave the tensor kernels unused: f16-act runs on the adapter's other kernels, as where the device has no
    /// cooperative matrices (the bench clears the GPU's `KernelChoice::coop`).
    pub no_coop: bool,
    /// The accuracy run: every official family at a small target size ([`sweep`]'s `ACCURACY`), each output
    /// against the float64 model (its f32-rounded twin not computed), PyTorch f32 and bf16 autocast beside,
    /// one timed run; with `--only`, `--precision`.
    pub accuracy: bool,
    /// Model files to measure too (e.g. trained models), with `scene` (or a synthetic scene).
    pub models: Vec<PathBuf>,
    pub scene: Option<PathBuf>,
    /// Measure only these sweep models, as (group, k), e.g. ("small", 2); no golden cases. Empty: all.
    pub only: Vec<(String, usize)>,
    /// Measure only these target sizes of the sweep. Empty: every size of each model's sweep.
    pub sizes: Vec<Size>,
    /// Also render this many target views at once at each measured sweep size, a measurement each (beside
    /// the one view every size gets).
    pub views: Vec<usize>,
    /// The command line, for the record.
    pub command: String,
}

/// A target size, (height, width).
pub type Size = (usize, usize);

/// The MSN-Easy setting of the paper: one 120×160 input view; target sizes of its Figure 2.
const INPUT_SIZE: (usize, usize) = (120, 160);
const FULL_SIZES: [(usize, usize); 5] = [(60, 80), (120, 160), (240, 320), (480, 640), (960, 1280)];
const QUICK_SIZES: [(usize, usize); 3] = [(60, 80), (120, 160), (240, 320)];
const PATCH_SIZES: [usize; 5] = [1, 2, 4, 8, 16];
/// Width of the small random models (the golden cases' structure).
const SMALL_WIDTH: usize = 32;
const SEED: u64 = 5;

/// Everything a measurement needs.
struct Bench {
    gpu: Arc<Gpu>,
    env: Environment,
    timestamps: bool,
    repeats: Repeats,
    max_render: Duration,
    /// Reference encodes and renders are computed when their multiply-adds (counted from the engine's ops)
    /// are at most this (the f64 CPU reference is slow).
    reference_macs: u64,
    torch: std::result::Result<pytorch::Torch, String>,
    scratch: PathBuf,
    quick: bool,
    only: Vec<(String, usize)>,
    /// The sweep's sizes measured (`Options::sizes`).
    sizes: Vec<Size>,
    /// Target views rendered at once too (`Options::views`).
    views: Vec<usize>,
    /// `Options::precisions`.
    precisions: Vec<Precision>,
    /// `Options::accuracy`.
    accuracy: bool,
}

/// The results file.
#[derive(Serialize, Deserialize)]
struct Results {
    command: String,
    date_unix: u64,
    environment: Environment,
    timing: String,
    pytorch: String,
    results: Vec<Record>,
    kernels: Vec<KernelTime>,
    paper_comparison: Vec<paper::Comparison>,
}

pub fn run(options: &Options) -> Result<()> {
    std::fs::create_dir_all(&options.out)
        .with_context(|| format!("{}: cannot create the output folder", options.out.display()))?;
    let scratch = options.out.join("scratch");
    std::fs::create_dir_all(&scratch).with_context(|| format!("{}: cannot create", scratch.display()))?;
    let adapter = options.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
    let gpu_options = GpuOptions {
        adapter,
        matmul: options.matmul,
        without_subgroups: options.without_subgroups,
        rays_on_host: options.rays_on_host,
        ..Default::default()
    };
    let mut gpu = Gpu::new(&gpu_options)?;
    if options.no_coop && gpu.kernels.coop.is_some() {
        gpu.kernels.coop = None;
        gpu.without_coop = Some("--no-coop".into());
    }
    let gpu = Arc::new(gpu);
    let timestamps = gpu.set_timestamps(TimestampMode::Plan).is_ok();
    let env = Environment {
        adapter: gpu.info.name.clone(),
        backend: format!("{:?}", gpu.info.backend),
        driver: format!("{} {}", gpu.info.driver, gpu.info.driver_info).trim().to_string(),
        machine: measure::machine(),
        matmul_kernel: format!("{:?}", gpu.kernels.matmul),
        subgroups: gpu.kernels.subgroups,
    };
    let torch = match options.pytorch.then(pytorch::probe) {
        None => Err("--no-pytorch".to_string()),
        Some(Err(why)) => Err(why),
        Some(Ok(installed)) => {
            let on_gpu = gpu.info.device_type != wgpu::DeviceType::Cpu;
            let torch = pytorch::Torch::choose(installed, options.pytorch_device, on_gpu, options.pytorch_compile)?;
            Ok(pytorch::Torch { autocast: options.pytorch_autocast || options.accuracy, ..torch })
        }
    };
    let runs = options.repeats.unwrap_or(if options.accuracy {
        1
    } else if options.quick {
        3
    } else {
        5
    });
    let warm_for = measure::warm_for(gpu.info.device_type);
    let bench = Bench {
        gpu,
        timestamps,
        repeats: Repeats {
            warmup: 1,
            warm_for,
            runs,
            budget: Duration::from_secs_f64(options.repeat_seconds.unwrap_or(if options.quick { 2.0 } else { 30.0 })),
        },
        max_render: Duration::from_secs_f64(options.max_render_seconds.unwrap_or(if options.quick {
            1.5
        } else {
            120.0
        })),
        reference_macs: match (options.max_reference_gmac, options.accuracy) {
            (Some(gmac), _) => (gmac * 1e9) as u64,
            (None, true) => u64::MAX,
            (None, false) => (if options.quick { 2.0 } else { 60.0 } * 1e9) as u64,
        },
        torch,
        scratch,
        quick: options.quick,
        only: options.only.clone(),
        sizes: options.sizes.clone(),
        views: options.views.clone(),
        precisions: options.precisions.clone(),
        accuracy: options.accuracy,
        env,
    };
    let timing = bench.timing();
    println!(
        "raypatch-bench{} on {} ({}, {})",
        if options.quick { " --quick" } else { "" },
        bench.env.adapter,
        bench.env.backend,
        bench.env.driver
    );
    println!(
        "machine: {}; timing: {timing}; matmul kernel: {}; subgroup variants: {}",
        bench.env.machine, bench.env.matmul_kernel, bench.env.subgroups
    );
    match &bench.torch {
        Ok(torch) => {
            println!("PyTorch: timing tools/reference/raypatch_reference.py on the same inputs, {}", torch.describe())
        }
        Err(why) => println!("PyTorch not timed: {why}"),
    }

    let started = report::progress::started();
    let mut records = Vec::new();
    let mut kernels = Vec::new();
    if options.only.is_empty() && !options.accuracy {
        bench.golden(&mut records)?;
    }
    // After each model, the results so far: a run cut short (a device call's time limit) keeps its tables.
    let mut checkpoint = |records: &[Record], kernels: &[KernelTime]| bench.write_results(options, records, kernels);
    bench.sweep(&mut records, &mut kernels, &mut checkpoint)?;
    bench.model_files(options, &mut records)?;
    let tables = bench.write_results(options, &records, &kernels)?;
    println!("\n{tables}");
    plots::draw_all(&records, &options.out)?;
    std::fs::remove_dir_all(&bench.scratch).ok();
    println!(
        "wrote results.json, results.csv, kernels.csv, tables.md and {} in {} ({:.0} s)",
        plots::FILES.join(", "),
        options.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn size_text((h, w): (usize, usize)) -> String {
    format!("{h}x{w}")
}

/// What the sweep calls after each size with the records so far (it writes them out).
type Checkpoint<'a> = dyn FnMut(&[Record], &[KernelTime]) -> Result<String> + 'a;

impl Bench {
    /// How times are taken: GPU timestamps where the adapter has them, else the wall clock.
    fn timing(&self) -> &'static str {
        if self.timestamps {
            "gpu timestamps"
        } else {
            "wall clock"
        }
    }

    /// Writes results.json, results.csv, kernels.csv and tables.md of `records` and `kernels` into the output
    /// folder; returns the tables.
    fn write_results(&self, options: &Options, records: &[Record], kernels: &[KernelTime]) -> Result<String> {
        let results = Results {
            command: options.command.clone(),
            date_unix: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()),
            environment: self.env.clone(),
            timing: self.timing().to_string(),
            pytorch: match &self.torch {
                Ok(torch) => torch.describe(),
                Err(why) => format!("not timed: {why}"),
            },
            results: records.to_vec(),
            kernels: kernels.to_vec(),
            paper_comparison: paper::compare(records),
        };
        let tables = report::tables::markdown(&results.results, &results.kernels, &results.pytorch)
            + &paper::markdown(&results.paper_comparison);
        let json = serde_json::to_string_pretty(&results)?;
        report::write_file(&options.out.join("results.json"), json.as_bytes())?;
        report::write_csv(&options.out.join("results.csv"), &results.results)?;
        report::write_csv(&options.out.join("kernels.csv"), &results.kernels)?;
        report::write_file(&options.out.join("tables.md"), tables.as_bytes())?;
        Ok(tables)
    }
}

/// The benchmark scene: `views` input views of `input` and `targets` target views of `target`, the same
/// cameras and images at every target size.
fn scene(
    views: usize,
    input: (usize, usize),
    targets: usize,
    target: (usize, usize),
) -> Result<(InputViews, TargetViews)> {
    synthetic::synthetic_scene(SEED, views, input, targets, target, &CameraRig::default()).map_err(anyhow::Error::msg)
}
