//! The benchmark run: which configurations are measured (quick and full), how each is measured, and where
//! the results go.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use raypatch_engine::gpu::{GpuTimes, TimestampMode};
use raypatch_engine::reference::model::{Argument, ReferenceModel, ReferenceScene};
use raypatch_engine::weights::{LoadOptions, WeightStorage};
use raypatch_engine::{
    AdapterChoice, EncodedScene, EngineError, Frame, Gpu, GpuOptions, Model, Outputs, Region, Request,
};
use raypatch_model::{InputViews, LoadedModel, TargetViews};
use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::flops;
use crate::measure::{self, Repeats, Sample, Stats};
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
    /// Measured runs per configuration (default 5, quick 3).
    pub repeats: Option<usize>,
    /// Skip configurations whose render is predicted (from its FLOPs and the rate measured at the previous
    /// size) to take longer than this (default 120 s, quick 1.5 s).
    pub max_render_seconds: Option<f64>,
    /// Time PyTorch on the same inputs when it is installed.
    pub pytorch: bool,
    /// Model files to measure too (e.g. trained models), with `scene` (or a synthetic scene).
    pub models: Vec<PathBuf>,
    pub scene: Option<PathBuf>,
    /// Measure only these sweep models, as (group, k), e.g. ("small", 2); no golden cases. Empty: all.
    pub only: Vec<(String, usize)>,
    /// The command line, for the record.
    pub command: String,
}

/// A target size, (height, width).
type Size = (usize, usize);

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
    /// Reference renders are computed when their MACs are below this (the f64 CPU reference is slow).
    reference_macs: u64,
    torch: std::result::Result<String, String>,
    scratch: PathBuf,
    quick: bool,
    only: Vec<(String, usize)>,
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

/// Writes tables.md and the plots again from results.json files (e.g. after changing how they are drawn).
/// With several files, later files' records replace earlier ones of the same configuration (model, decoder,
/// k, precision, target size, variant) and the others are kept: a partial run (`--only`) updates a full one.
/// The merged results.json, results.csv and kernels.csv are written into `out` too.
pub fn replot(files: &[PathBuf], out: &Path) -> Result<()> {
    let mut merged: Option<Results> = None;
    for file in files {
        let text = std::fs::read_to_string(file).with_context(|| format!("{}: cannot read", file.display()))?;
        let next: Results = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a raypatch-bench results.json", file.display()))?;
        merged = Some(match merged {
            None => next,
            Some(mut all) => {
                let key = |r: &Record| {
                    (
                        r.model.clone(),
                        r.decoder.clone(),
                        r.k,
                        r.precision.clone(),
                        r.target_size.clone(),
                        r.variant.clone(),
                    )
                };
                for record in next.results {
                    match all.results.iter_mut().find(|r| key(r) == key(&record)) {
                        Some(old) => *old = record,
                        None => all.results.push(record),
                    }
                }
                let configs: Vec<String> = next.kernels.iter().map(|k| k.config.clone()).collect();
                all.kernels.retain(|k| !configs.contains(&k.config));
                all.kernels.extend(next.kernels);
                all.command = format!("{}\n{}", all.command, next.command);
                all.paper_comparison = paper::compare(&all.results);
                all
            }
        });
    }
    let results = merged.context("no results.json to replot")?;
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create the output folder", out.display()))?;
    if files.len() > 1 {
        let json = serde_json::to_string_pretty(&results)?;
        report::write_file(&out.join("results.json"), json.as_bytes())?;
        report::write_csv(&out.join("results.csv"), &results.results)?;
        report::write_csv(&out.join("kernels.csv"), &results.kernels)?;
    }
    let tables = report::markdown(&results.results, &results.kernels, &results.paper_comparison);
    report::write_file(&out.join("tables.md"), tables.as_bytes())?;
    plots::draw_all(&results.results, out)?;
    println!("wrote tables.md and {} in {}", plots::FILES.join(", "), out.display());
    Ok(())
}

/// Both float64 references of a model (f32-rounded and float64 encoding arguments) with their encodings.
type References = (ReferenceModel, ReferenceScene, ReferenceModel, ReferenceScene);

/// One model under test with its encoded scene (engine and references).
struct Subject<'a> {
    name: String,
    group: &'static str,
    loaded: &'a LoadedModel,
    /// The model as a file, for PyTorch.
    file: Option<&'a [u8]>,
    model: &'a Model,
    storage: WeightStorage,
    inputs: &'a InputViews,
    encode: (Stats, Option<Stats>),
    encoded: EncodedScene<'a>,
    references: Option<&'a References>,
}

pub fn run(options: &Options) -> Result<()> {
    std::fs::create_dir_all(&options.out)
        .with_context(|| format!("{}: cannot create the output folder", options.out.display()))?;
    let scratch = options.out.join("scratch");
    std::fs::create_dir_all(&scratch).with_context(|| format!("{}: cannot create", scratch.display()))?;
    let adapter = options.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
    let gpu = Arc::new(Gpu::new(&GpuOptions { adapter, ..Default::default() })?);
    let timestamps = gpu.set_timestamps(TimestampMode::Plan).is_ok();
    let env = Environment {
        adapter: gpu.info.name.clone(),
        backend: format!("{:?}", gpu.info.backend),
        driver: format!("{} {}", gpu.info.driver, gpu.info.driver_info).trim().to_string(),
        machine: measure::machine(),
    };
    let torch = if options.pytorch { pytorch::probe() } else { Err("--no-pytorch".to_string()) };
    let runs = options.repeats.unwrap_or(if options.quick { 3 } else { 5 });
    let bench = Bench {
        gpu,
        timestamps,
        repeats: Repeats { warmup: 1, runs, budget: Duration::from_secs(if options.quick { 2 } else { 30 }) },
        max_render: Duration::from_secs_f64(options.max_render_seconds.unwrap_or(if options.quick {
            1.5
        } else {
            120.0
        })),
        reference_macs: if options.quick { 2_000_000_000 } else { 60_000_000_000 },
        torch,
        scratch,
        quick: options.quick,
        only: options.only.clone(),
        env,
    };
    let timing = if bench.timestamps { "gpu timestamps" } else { "wall clock" };
    println!(
        "raypatch-bench{} on {} ({}, {})",
        if options.quick { " --quick" } else { "" },
        bench.env.adapter,
        bench.env.backend,
        bench.env.driver
    );
    println!("machine: {}; timing: {timing}", bench.env.machine);
    match &bench.torch {
        Ok(version) => {
            println!("PyTorch {version}: timing tools/raypatch_reference.py on the same inputs")
        }
        Err(why) => println!("PyTorch not timed: {why}"),
    }

    let started = started();
    let mut records = Vec::new();
    let mut kernels = Vec::new();
    if options.only.is_empty() {
        bench.golden(&mut records)?;
    }
    bench.sweep(&mut records, &mut kernels)?;
    bench.model_files(options, &mut records)?;
    let comparison = paper::compare(&records);

    let tables = report::markdown(&records, &kernels, &comparison);
    println!("\n{tables}");
    let results = Results {
        command: options.command.clone(),
        date_unix: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()),
        environment: bench.env.clone(),
        timing: timing.to_string(),
        pytorch: match &bench.torch {
            Ok(v) => format!("torch {v}"),
            Err(why) => format!("not timed: {why}"),
        },
        results: records,
        kernels,
        paper_comparison: comparison,
    };
    let json = serde_json::to_string_pretty(&results)?;
    report::write_file(&options.out.join("results.json"), json.as_bytes())?;
    report::write_csv(&options.out.join("results.csv"), &results.results)?;
    report::write_csv(&options.out.join("kernels.csv"), &results.kernels)?;
    report::write_file(&options.out.join("tables.md"), tables.as_bytes())?;
    plots::draw_all(&results.results, &options.out)?;
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

fn precision_name(storage: WeightStorage) -> &'static str {
    match storage {
        WeightStorage::F32 => "f32",
        WeightStorage::F16 => "f16",
    }
}

fn decoder_name(k: usize) -> String {
    if k == 1 { "SRT" } else { "RP-SRT" }.to_string()
}

impl Bench {
    /// A render's wall time and, with timestamps, its GPU time.
    fn render_sample(&self, encoded: &EncodedScene, targets: &TargetViews, request: Request) -> Result<Sample> {
        let start = Instant::now();
        encoded.render(targets, request)?;
        let wall = start.elapsed();
        Ok(Sample { wall, gpu: self.gpu.take_timestamps()?.map(|t| t.total) })
    }

    /// Encodes `inputs` repeatedly; returns the timings and the last encoded scene.
    fn encode<'m>(&self, model: &'m Model, inputs: &InputViews) -> Result<((Stats, Option<Stats>), EncodedScene<'m>)> {
        let mut last = None;
        let stats = measure::repeat(self.repeats, || -> Result<Sample> {
            let start = Instant::now();
            let encoded = model.encode(inputs)?;
            let wall = start.elapsed();
            let gpu = self.gpu.take_timestamps()?.map(|t| t.total);
            last = Some(encoded);
            Ok(Sample { wall, gpu })
        })?;
        Ok((stats, last.expect("at least one encode")))
    }

    /// Both float64 references of a model and their encodings, when affordable.
    fn references(&self, loaded: &LoadedModel, inputs: &InputViews) -> Result<Option<References>> {
        let macs = flops::encode_macs(&loaded.config, inputs.count, inputs.height, inputs.width);
        if macs > self.reference_macs {
            return Ok(None);
        }
        let f32_args = ReferenceModel::new(loaded, Argument::RoundedToF32);
        let f64_args = ReferenceModel::new(loaded, Argument::Float64);
        let (a, b) = (f32_args.encode(inputs)?, f64_args.encode(inputs)?);
        Ok(Some((f32_args, a, f64_args, b)))
    }

    #[allow(clippy::too_many_arguments)]
    fn subject<'a>(
        &self,
        name: String,
        group: &'static str,
        loaded: &'a LoadedModel,
        file: Option<&'a [u8]>,
        model: &'a Model,
        storage: WeightStorage,
        inputs: &'a InputViews,
        references: Option<&'a References>,
    ) -> Result<Subject<'a>> {
        let (encode, encoded) = self.encode(model, inputs)?;
        Ok(Subject { name, group, loaded, file, model, storage, inputs, encode, encoded, references })
    }

    /// The fields of a record that do not need a measurement: the configuration, its FLOPs, the memory a
    /// materialised softmax would take.
    fn record(&self, s: &Subject, views: usize, size: (usize, usize), variant: &str) -> Record {
        let cfg = &s.loaded.config;
        let k = cfg.patch_size();
        let tokens = flops::tokens(cfg, s.inputs.count, s.inputs.height, s.inputs.width);
        let queries = views * (size.0 / k) * (size.1 / k);
        Record {
            group: s.group.to_string(),
            model: s.name.clone(),
            decoder: decoder_name(k),
            k,
            precision: precision_name(s.storage).into(),
            variant: variant.to_string(),
            parameters: s.loaded.parameter_count(),
            weight_bytes: s.model.weight_bytes(),
            input_views: s.inputs.count,
            input_size: size_text((s.inputs.height, s.inputs.width)),
            target_views: views,
            target_size: size_text(size),
            pixels: views * size.0 * size.1,
            queries,
            tokens,
            timing: if self.timestamps { "gpu timestamps" } else { "wall clock" }.into(),
            encode_ms: s.encode.1.or(Some(s.encode.0)),
            encode_wall_ms: Some(s.encode.0),
            encode_peak_bytes: Some(s.encoded.encode_peak_bytes),
            attention_scores_bytes: flops::attention_score_bytes(queries, tokens, cfg.decoder.heads),
            encode_gflop: 2.0 * flops::encode_macs(cfg, s.inputs.count, s.inputs.height, s.inputs.width) as f64 / 1e9,
            render_gflop: 2.0 * flops::render_macs(cfg, views, size.0, size.1, tokens) as f64 / 1e9,
            env: Some(self.env.clone()),
            ..Default::default()
        }
    }

    /// Renders once (building the plan), then times repeated renders; fills the record's timing, memory and
    /// work fields and returns the first frame.
    fn time_render(&self, s: &Subject, targets: &TargetViews, request: Request, record: &mut Record) -> Result<Frame> {
        let start = Instant::now();
        let frame = s.encoded.render(targets, request)?;
        record.first_render_wall_ms = Some(start.elapsed().as_secs_f64() * 1e3);
        self.gpu.take_timestamps()?;
        let stats = s.encoded.render_stats(targets, request)?;
        (record.render_peak_bytes, record.dispatches, record.queries) =
            (Some(stats.peak_bytes), Some(stats.dispatches), stats.queries);
        // The first render was the warm-up (it built the plan).
        let repeats = Repeats { warmup: 0, ..self.repeats };
        let (wall, mut gpu) = measure::repeat(repeats, || self.render_sample(&s.encoded, targets, request))?;
        if stats.bands > 1 {
            // Timestamps cover the last band's plan only: time the whole banded render by the wall clock.
            gpu = None;
            record.note = format!("{} row bands (largest buffer over the adapter's limit), wall clock", stats.bands);
        }
        set_times(record, wall, gpu);
        Ok(frame)
    }

    /// Measures one render configuration of a subject. `truth`: PyTorch's rgb for these targets, if known.
    fn measure(&self, s: &Subject, targets: &TargetViews, truth: Option<&[f32]>, with_torch: bool) -> Result<Record> {
        let grid = s.loaded.config.target_grid(targets, "target views")?;
        let mut record = self.record(s, targets.count, (grid.height, grid.width), "");
        let frame = self.time_render(s, targets, Outputs::default().into(), &mut record)?;
        let rgb = frame.rgb.context("a default render has rgb")?;
        let render_macs = (record.render_gflop / 2.0 * 1e9) as u64;
        match s.references {
            Some((f32_args, f32_scene, f64_args, f64_scene)) if render_macs <= self.reference_macs => {
                let want = f32_args.render(f32_scene, targets)?;
                record.max_err_f64_reference = Some(measure::max_abs_error(&rgb, &want.rgb));
                record.rms_err_f64_reference = Some(measure::rms_error(&rgb, &want.rgb));
                let exact = f64_args.render(f64_scene, targets)?;
                record.max_err_f64_model = Some(measure::max_abs_error(&rgb, &exact.rgb));
            }
            _ => {
                record.note =
                    format!("{}; no f64 reference (too slow at this size)", record.note).trim_start_matches("; ").into()
            }
        }
        if let Some(truth) = truth {
            record.max_err_pytorch = Some(max_abs_f32(&rgb, truth));
        }
        if let Some(images) = &targets.images {
            record.psnr_db = Some(measure::psnr(&rgb, images, targets.count));
        }
        if with_torch {
            // PyTorch failing (e.g. out of memory at a large size) is reported in the record, not fatal.
            if let Err(e) = self.time_pytorch(s, targets, &rgb, &mut record) {
                record.note = format!("{} PyTorch failed: {e:#}", record.note).trim().to_string();
            }
        }
        print_row(&record);
        Ok(record)
    }

    fn time_pytorch(&self, s: &Subject, targets: &TargetViews, rgb: &[f32], record: &mut Record) -> Result<()> {
        let (Ok(_), Some(file)) = (&self.torch, s.file) else {
            return Ok(());
        };
        // Model-file subjects are named by their path: keep the scratch file name flat.
        let flat: String = s.name.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
        let model_path = self.scratch.join(format!("{flat}-k{}.safetensors", record.k));
        if !model_path.exists() {
            report::write_file(&model_path, file)?;
        }
        let scene_path = self.scratch.join(format!("scene-{}.safetensors", record.target_size));
        report::write_file(&scene_path, &scene_file(s.inputs, targets)?)?;
        let repeats = if self.quick { 1 } else { 3 };
        let run = pytorch::run(&model_path, &scene_path, repeats)?;
        record.max_err_pytorch = Some(max_abs_f32(rgb, &run.rgb));
        record.pytorch_over_ours = record.render_wall_ms.map(|ours| run.render.median_ms / ours.median_ms);
        record.note = format!("{} PyTorch on {} CPU threads", record.note, run.threads).trim().to_string();
        record.pytorch_encode_ms = Some(run.encode);
        record.pytorch_render_ms = Some(run.render);
        Ok(())
    }

    /// Every golden case: errors against PyTorch's float32 output and both float64 references, PSNR where the
    /// scene has ground truth.
    fn golden(&self, records: &mut Vec<Record>) -> Result<()> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/golden");
        let mut cases: Vec<PathBuf> = std::fs::read_dir(&dir)
            .with_context(|| format!("{}: the golden cases are missing", dir.display()))?
            .map(|e| e.map(|e| e.path()))
            .collect::<std::io::Result<_>>()?;
        cases.retain(|p| p.join("expected.safetensors").exists());
        cases.sort();
        println!("golden cases (assets/golden): errors against PyTorch and the float64 reference");
        for case in cases {
            let name = case.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let loaded = raypatch_model::load_model(case.join("model.safetensors"))?;
            let scene = raypatch_model::load_scene(case.join("scene.safetensors"))?;
            let truth = raypatch_model::TensorFile::open(&case.join("expected.safetensors"))?.f32("rgb")?.data;
            let model = Model::from_loaded(self.gpu.clone(), &loaded)?;
            let references = self.references(&loaded, &scene.inputs)?;
            let subject = self.subject(
                name,
                "golden",
                &loaded,
                None,
                &model,
                WeightStorage::F32,
                &scene.inputs,
                references.as_ref(),
            )?;
            records.push(self.measure(&subject, &scene.targets, Some(&truth), false)?);
            if loaded.config.image_channels() == 4 {
                records.extend(self.logdepth_skip(&subject, &scene.targets)?);
            }
        }
        Ok(())
    }

    /// Outputs not asked for are not computed: rgb only, rgb and log-depth, log-depth only.
    fn logdepth_skip(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<Record>> {
        let grid = s.loaded.config.target_grid(targets, "target views")?;
        let mut rows = Vec::new();
        let variants = [
            ("outputs: rgb", Outputs { rgb: true, logdepth: false }),
            ("outputs: rgb + log-depth", Outputs { rgb: true, logdepth: true }),
            ("outputs: log-depth", Outputs { rgb: false, logdepth: true }),
        ];
        for (variant, outputs) in variants {
            let mut record = self.record(s, targets.count, (grid.height, grid.width), variant);
            record.group = "skips".into();
            self.time_render(s, targets, outputs.into(), &mut record)?;
            print_row(&record);
            rows.push(record);
        }
        Ok(rows)
    }

    /// Random-weight models: small and official size, SRT and RP-SRT k ∈ {2, 4, 8, 16}, over target sizes.
    fn sweep(&self, records: &mut Vec<Record>, kernels: &mut Vec<KernelTime>) -> Result<()> {
        let (small_sizes, official): (&[Size], Vec<(usize, &[Size])>) = if self.quick {
            (&QUICK_SIZES, vec![(8, &[(120, 160)])])
        } else {
            (&FULL_SIZES, PATCH_SIZES.iter().map(|&k| (k, &FULL_SIZES[..])).collect())
        };
        let mut specs: Vec<(&str, usize, serde_json::Value, &[Size])> =
            PATCH_SIZES.iter().map(|&k| ("small", k, synthetic::small_config(k, SMALL_WIDTH), small_sizes)).collect();
        for (k, sizes) in official {
            let config = if k == 1 { synthetic::official_srt_config() } else { synthetic::official_rpsrt_config(k) };
            specs.push(("official", k, config, sizes));
        }
        println!("random-weight models, 1 input view {}x{}, 1 target view", INPUT_SIZE.0, INPUT_SIZE.1);
        let f16 = self.gpu.features.contains(raypatch_engine::wgpu::Features::SHADER_F16);
        if !self.only.is_empty() {
            specs.retain(|(name, k, _, _)| self.only.iter().any(|(n, only_k)| n == name && only_k == k));
        }
        for (name, k, config, sizes) in specs {
            let (loaded, file) = synthetic::random_model(&config, SEED + k as u64, name)?;
            let (inputs, _) = scene(INPUT_SIZE)?;
            let references = self.references(&loaded, &inputs)?;
            let mut storages = vec![WeightStorage::F32];
            if f16 && (name == "small" || !self.quick) {
                storages.push(WeightStorage::F16);
            }
            let mut sizes: Vec<(usize, usize)> =
                sizes.iter().filter(|s| s.0 % k == 0 && s.1 % k == 0).copied().collect();
            for storage in storages {
                let model =
                    Model::from_loaded_with(self.gpu.clone(), &loaded, &LoadOptions { weight_storage: storage })?;
                let subject = self.subject(
                    name.to_string(),
                    "sweep",
                    &loaded,
                    Some(&file),
                    &model,
                    storage,
                    &inputs,
                    references.as_ref(),
                )?;
                let measured = self.sweep_sizes(&subject, &sizes, records, kernels)?;
                // f16 at the paper's sizes that f32 rendered: precision does not change how time scales with size.
                let f16_sizes: &[(usize, usize)] = if self.quick { &[(120, 160)] } else { &[(60, 80), (120, 160)] };
                sizes = measured.into_iter().filter(|s| f16_sizes.contains(s)).collect();
            }
        }
        Ok(())
    }

    /// One subject over target sizes (ascending): sizes predicted to render slower than the limit are skipped.
    /// Returns the sizes rendered.
    fn sweep_sizes(
        &self,
        s: &Subject,
        sizes: &[(usize, usize)],
        records: &mut Vec<Record>,
        kernels: &mut Vec<KernelTime>,
    ) -> Result<Vec<(usize, usize)>> {
        let mut measured = Vec::new();
        let (name, k, f32_weights) = (s.name.as_str(), s.loaded.config.patch_size(), s.storage == WeightStorage::F32);
        let mut rate: Option<f64> = None;
        for &size in sizes {
            let (_, targets) = scene(size)?;
            let tokens = flops::tokens(&s.loaded.config, 1, INPUT_SIZE.0, INPUT_SIZE.1);
            let macs = flops::render_macs(&s.loaded.config, 1, size.0, size.1, tokens);
            if let Some(rate) = rate {
                let predicted = macs as f64 / rate;
                if predicted > self.max_render.as_secs_f64() {
                    println!(
                        "  {name:<12} {:<7} k={k:<2} {:>9} skipped: predicted {predicted:.0} s per render",
                        decoder_name(k),
                        size_text(size)
                    );
                    records.push(self.skipped(s, &targets, predicted)?);
                    continue;
                }
            }
            let with_torch = f32_weights && self.torch_config(name, k, size);
            let mut record = match self.measure(s, &targets, None, with_torch) {
                Ok(record) => record,
                // A plan needing a buffer beyond the adapter's binding limit is a result, not a failure.
                Err(e) if matches!(e.downcast_ref::<EngineError>(), Some(EngineError::TooLarge { .. })) => {
                    println!("  {name:<12} {:<7} k={k:<2} {:>9} does not fit: {e}", decoder_name(k), size_text(size));
                    let mut record = self.record(s, targets.count, size, "");
                    record.note = format!("does not fit: {e}");
                    records.push(record);
                    s.encoded.clear_render_plans();
                    continue;
                }
                Err(e) => return Err(e),
            };
            if !s.model.weights_kept_f32().is_empty() {
                let kept: Vec<&str> = s.model.weights_kept_f32().iter().map(|k| k.tensor.as_str()).collect();
                record.note =
                    format!("{} kept in f32 (beyond f16 range): {}", record.note, kept.join(" ")).trim().to_string();
            }
            rate = record.render_wall_ms.map(|r| macs as f64 / (r.median_ms / 1e3));
            records.push(record);
            measured.push(size);
            if f32_weights && self.breakdown_config(name, k, size) {
                kernels.extend(self.kernel_breakdown(s, &targets)?);
            }
            let skips = (name == "small" && k == 4) || (!self.quick && name == "official" && k == 8);
            if f32_weights && skips && size == (120, 160) {
                records.extend(self.plan_and_encode_skips(s, &targets)?);
            }
            // Free this size's plan (its buffers) before the next, larger one.
            s.encoded.clear_render_plans();
        }
        Ok(measured)
    }

    fn torch_config(&self, name: &str, k: usize, size: (usize, usize)) -> bool {
        match (self.quick, name) {
            (true, _) => k == 4 && size == (60, 80) && name == "small",
            (false, "small") => size == (120, 160) && (k == 1 || k == 4),
            (false, _) => (size == (60, 80) && k <= 4) || (size == (120, 160) && k >= 4),
        }
    }

    fn breakdown_config(&self, name: &str, k: usize, size: (usize, usize)) -> bool {
        size == (120, 160) && (name == "official" && (k == 1 || k == 8) || name == "small" && k == 4)
    }

    /// A size not rendered: its FLOPs and planned memory (the plan is built, not run) with the prediction.
    fn skipped(&self, s: &Subject, targets: &TargetViews, predicted: f64) -> Result<Record> {
        let grid = s.loaded.config.target_grid(targets, "target views")?;
        let mut record = self.record(s, targets.count, (grid.height, grid.width), "");
        record.note = format!("skipped: predicted {predicted:.0} s per render on this adapter");
        match s.encoded.render_stats(targets, Outputs::default()) {
            Ok(stats) => {
                (record.render_peak_bytes, record.dispatches) = (Some(stats.peak_bytes), Some(stats.dispatches))
            }
            Err(e @ EngineError::TooLarge { .. }) => record.note += &format!("; does not fit: {e}"),
            Err(e) => return Err(e.into()),
        }
        s.encoded.clear_render_plans();
        Ok(record)
    }

    /// The skips of the API, on and off: the plan cache, the per-scene encoding, and a region of interest.
    fn plan_and_encode_skips(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<Record>> {
        let full = Request::from(Outputs::default());
        let grid = s.loaded.config.target_grid(targets, "target views")?;
        let size = (grid.height, grid.width);
        let row = |variant: &str, wall: Stats, request: Request| -> Result<Record> {
            let mut record = self.record(s, targets.count, size, variant);
            record.group = "skips".into();
            record.timing = "wall clock".into();
            set_times(&mut record, wall, None);
            let stats = s.encoded.render_stats(targets, request)?;
            (record.render_peak_bytes, record.dispatches, record.queries) =
                (Some(stats.peak_bytes), Some(stats.dispatches), stats.queries);
            print_row(&record);
            Ok(record)
        };
        let wall = |f: &dyn Fn() -> Result<()>| {
            measure::repeat(self.repeats, || -> Result<Sample> {
                let start = Instant::now();
                f()?;
                self.gpu.take_timestamps()?;
                Ok(Sample { wall: start.elapsed(), gpu: None })
            })
            .map(|(wall, _)| wall)
        };
        let cached = wall(&|| s.encoded.render(targets, full).map(drop).map_err(Into::into))?;
        // Without the plan cache every render builds its plan (buffers, params, bind groups) first.
        let rebuilt = wall(&|| {
            s.encoded.clear_render_plans();
            s.encoded.render(targets, full)?;
            Ok(())
        })?;
        let build = wall(&|| {
            s.encoded.clear_render_plans();
            s.encoded.render_stats(targets, full)?;
            Ok(())
        })?;
        // Without the per-scene encoding every render encodes the input views (latent, keys, values) again.
        let encode_each = wall(&|| {
            let encoded = s.model.encode(s.inputs)?;
            self.gpu.take_timestamps()?;
            encoded.render(targets, full)?;
            Ok(())
        })?;
        // A region of interest: the top-left quarter of the image; only the patches it needs are decoded.
        let quarter = Request { region: Some(Region { x: 0, y: 0, width: size.1 / 2, height: size.0 / 2 }), ..full };
        s.encoded.render(targets, quarter)?;
        let region = wall(&|| s.encoded.render(targets, quarter).map(drop).map_err(Into::into))?;
        Ok(vec![
            row("plan cached, scene encoded once", cached, full)?,
            row("plan rebuilt per render", rebuilt, full)?,
            Record { fps: None, ..row("(plan build alone)", build, full)? },
            row("scene encoded per render", encode_each, full)?,
            row("region: top-left quarter", region, quarter)?,
        ])
    }

    /// One render with a timestamp between every two ops, summed per op (layer indices and query chunks
    /// folded) and per kernel.
    fn kernel_breakdown(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<KernelTime>> {
        if self.gpu.set_timestamps(TimestampMode::Ops).is_err() {
            return Ok(Vec::new());
        }
        let times = (|| -> Result<Option<GpuTimes>> {
            s.encoded.render(targets, Outputs::default())?;
            Ok(self.gpu.take_timestamps()?)
        })();
        self.gpu.set_timestamps(TimestampMode::Plan)?;
        let Some(times) = times? else { bail!("no timestamps came back") };
        let k = s.loaded.config.patch_size();
        let grid = s.loaded.config.target_grid(targets, "target views")?;
        let config = format!(
            "{} {} k={k} {}x{} {}",
            s.name,
            decoder_name(k),
            grid.height,
            grid.width,
            precision_name(s.storage)
        );
        Ok(crate::kernels::fold(&config, &times))
    }

    /// Model files given on the command line, on their scene (or a synthetic one).
    fn model_files(&self, options: &Options, records: &mut Vec<Record>) -> Result<()> {
        for path in &options.models {
            let loaded = raypatch_model::load_model(path)?;
            let (inputs, targets) = match &options.scene {
                Some(scene) => {
                    let s = raypatch_model::load_scene(scene)?;
                    (s.inputs, s.targets)
                }
                None => scene((120, 160))?,
            };
            let model = Model::from_loaded(self.gpu.clone(), &loaded)?;
            let file = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
            let references = self.references(&loaded, &inputs)?;
            let name = path.display().to_string();
            let subject = self.subject(
                name,
                "model",
                &loaded,
                Some(&file),
                &model,
                WeightStorage::F32,
                &inputs,
                references.as_ref(),
            )?;
            records.push(self.measure(&subject, &targets, None, true)?);
        }
        Ok(())
    }
}

/// When the run started, for the progress lines.
fn started() -> Instant {
    static START: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    *START.get_or_init(Instant::now)
}

/// Fills the render timing fields: GPU time when there is one, else wall time.
fn set_times(record: &mut Record, wall: Stats, gpu: Option<Stats>) {
    let render = gpu.unwrap_or(wall);
    record.render_ms = Some(render);
    record.render_wall_ms = Some(wall);
    record.fps = Some(1e3 * record.target_views as f64 / render.median_ms);
}

fn print_row(r: &Record) {
    println!(
        "  [{:>5.0} s] {:<12} {:<7} k={:<2} {} {:>9} {:<32} render {:>9.2} ms ({:>8.1} fps), encode {:>8.1} ms, peak {:>9}, err {}",
        started().elapsed().as_secs_f64(),
        r.model,
        r.decoder,
        r.k,
        r.precision,
        r.target_size,
        r.variant,
        r.render_ms.map_or(0.0, |s| s.median_ms),
        r.fps.unwrap_or(0.0),
        r.encode_ms.map_or(0.0, |e| e.median_ms),
        r.render_peak_bytes.map_or("-".into(), report::bytes),
        report::sci(r.max_err_f64_reference),
    );
}

fn max_abs_f32(a: &[f32], b: &[f32]) -> f64 {
    let b: Vec<f64> = b.iter().map(|&v| v as f64).collect();
    measure::max_abs_error(a, &b)
}

/// The benchmark scene: one input view of [`INPUT_SIZE`] and one target view of `target`, the same cameras
/// and image at every target size.
fn scene(target: (usize, usize)) -> Result<(InputViews, TargetViews)> {
    synthetic::synthetic_scene(SEED, 1, INPUT_SIZE, 1, target, &CameraRig::default()).map_err(anyhow::Error::msg)
}

/// A scene file (docs/FORMATS.md) of these views, for PyTorch.
fn scene_file(inputs: &InputViews, targets: &TargetViews) -> Result<Vec<u8>> {
    let (n, h, w) = (inputs.count, inputs.height, inputs.width);
    let t = targets.count;
    let (th, tw) = (targets.rays_height, targets.rays_width);
    let tensors = vec![
        ("input_images".to_string(), vec![n, h, w, 3], inputs.images.clone()),
        ("input_camera_pos".to_string(), vec![n, 3], inputs.camera_pos.clone()),
        ("input_rays".to_string(), vec![n, h, w, 3], inputs.rays.clone()),
        ("target_camera_pos".to_string(), vec![t, 3], targets.camera_pos.clone()),
        ("target_rays".to_string(), vec![t, th, tw, 3], targets.rays.clone()),
    ];
    let metadata = json!({"format": "raypatch-scene/1"});
    let metadata = metadata
        .as_object()
        .expect("object")
        .iter()
        .map(|(k, v)| (k.clone(), v.as_str().unwrap_or_default().to_string()))
        .collect();
    synthetic::serialize(&tensors, metadata).map_err(anyhow::Error::msg)
}
