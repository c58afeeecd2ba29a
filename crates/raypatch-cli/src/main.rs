//! render-frame: render the target views of a scene with an SRT or RP-SRT model.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Parser;
use raypatch_engine::{AdapterChoice, Frame, Gpu, GpuOptions, Model, Outputs};
use safetensors::tensor::TensorView;
use safetensors::Dtype;

/// The bundled model and scene rendered when none is given.
const DEFAULT_MODEL: &str = "assets/golden/rpsrt_k4/model.safetensors";
const DEFAULT_SCENE: &str = "assets/golden/rpsrt_k4/scene.safetensors";

#[derive(Parser, Debug)]
#[command(name = "render-frame", version, about = "Render novel views with an SRT / RP-SRT model on the GPU")]
struct Args {
    /// Model file (safetensors with the official key names and the config in its metadata).
    #[arg(long, default_value = DEFAULT_MODEL)]
    model: PathBuf,
    /// Scene file (safetensors: input views and target cameras, see docs/FORMATS.md).
    #[arg(long, default_value = DEFAULT_SCENE)]
    scene: PathBuf,
    /// Folder to write one PNG per target view into.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Safetensors file to write the raw output into: `rgb` [T,H,W,3] f32 after the sigmoid.
    #[arg(long)]
    out_raw: Option<PathBuf>,
    /// Adapter to use: the first whose name contains this text (default: a real GPU, else lavapipe).
    #[arg(long)]
    adapter: Option<String>,
    /// Print encode and render times and the planned peak memory.
    #[arg(long)]
    timings: bool,
    /// Time every op of the encode and render plans (run one by one) and print the slowest.
    #[arg(long)]
    profile: bool,
    /// Render this many times after the first (warm) render and report the median (with --timings).
    #[arg(long, default_value_t = 0)]
    repeat: usize,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("render-frame: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &Args) -> Result<()> {
    let options = GpuOptions {
        adapter: args.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains),
    };
    let gpu = Arc::new(Gpu::new(&options)?);
    let scene_file = raypatch_model::load_scene(&args.scene)?;
    let start = Instant::now();
    let model = Model::load(gpu.clone(), &args.model)?;
    let load_time = start.elapsed();
    scene_file.inputs.check_for(&model.config, &scene_file.path)?;
    scene_file.targets.grid(model.config.patch_size(), &scene_file.path)?;
    check_output_paths(args)?;

    let start = Instant::now();
    let scene = model.encode(&scene_file.inputs)?;
    let encode_time = start.elapsed();
    let start = Instant::now();
    let frame = scene.render(&scene_file.targets, Outputs::default())?;
    let first_render = start.elapsed();
    let mut renders = Vec::with_capacity(args.repeat);
    for _ in 0..args.repeat {
        let start = Instant::now();
        scene.render(&scene_file.targets, Outputs::default())?;
        renders.push(start.elapsed().as_secs_f64());
    }

    if let Some(path) = &args.out_raw {
        write_raw(path, &frame)?;
    }
    if let Some(dir) = &args.out {
        write_pngs(dir, &frame)?;
    }
    let k = model.config.patch_size();
    println!(
        "rendered {} view(s) of {}x{} with {} ({}, k={k}, {:.1}M parameters) on {}",
        frame.views,
        frame.height,
        frame.width,
        model.path,
        if k == 1 { "SRT" } else { "RP-SRT" },
        model.parameter_count as f64 / 1e6,
        gpu.describe()
    );
    if args.timings {
        let mib = |b: u64| b as f64 / (1 << 20) as f64;
        println!("load {:.1} ms, encode {:.1} ms, first render {:.1} ms (plan built, pipelines compiled)",
            load_time.as_secs_f64() * 1e3, encode_time.as_secs_f64() * 1e3, first_render.as_secs_f64() * 1e3);
        if !renders.is_empty() {
            renders.sort_by(f64::total_cmp);
            println!(
                "render: median {:.1} ms, min {:.1} ms, max {:.1} ms over {} runs",
                renders[renders.len() / 2] * 1e3,
                renders[0] * 1e3,
                renders[renders.len() - 1] * 1e3,
                renders.len()
            );
        }
        println!(
            "planned peak GPU memory: render {:.2} MiB, encode {:.2} MiB; weights {:.2} MiB; scene cache {:.2} MiB",
            mib(scene.render_peak_bytes(&scene_file.targets, Outputs::default())?),
            mib(scene.encode_peak_bytes),
            mib(model.weight_bytes()),
            mib(scene.latent.bytes() + scene.keys_values.iter().map(|t| t.bytes()).sum::<u64>())
        );
    }
    if args.profile {
        let (_, encode_ops) = model.encode_profiled(&scene_file.inputs)?;
        print_profile("encode", &encode_ops);
        print_profile("render", &scene.profile_render(&scene_file.targets, Outputs::default())?);
    }
    Ok(())
}

/// The slowest ops of a plan, with their share of the plan's total.
fn print_profile(what: &str, ops: &[(String, std::time::Duration)]) {
    let total: f64 = ops.iter().map(|(_, t)| t.as_secs_f64()).sum();
    println!("{what}: {} ops, {:.1} ms run one by one; slowest:", ops.len(), total * 1e3);
    let mut sorted: Vec<_> = ops.iter().collect();
    sorted.sort_by(|a, b| b.1.cmp(&a.1));
    for (label, t) in sorted.iter().take(12) {
        let ms = t.as_secs_f64() * 1e3;
        println!("  {ms:8.2} ms {:5.1}%  {label}", 100.0 * t.as_secs_f64() / total);
    }
}

/// Fails before any work is done when an output cannot be written.
fn check_output_paths(args: &Args) -> Result<()> {
    if let Some(path) = &args.out_raw {
        let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        if !dir.is_dir() {
            bail!("--out-raw {}: folder {} does not exist", path.display(), dir.display());
        }
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("--out {}: cannot create the folder", dir.display()))?;
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file and a rename, so no partial file is left behind.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp"));
    std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", path.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}

fn write_raw(path: &Path, frame: &Frame) -> Result<()> {
    let mut tensors: Vec<(String, Vec<u8>, Vec<usize>)> =
        vec![("rgb".into(), f32_bytes(&frame.rgb), vec![frame.views, frame.height, frame.width, 3])];
    if let Some(d) = &frame.logdepth {
        tensors.push(("logdepth".into(), f32_bytes(d), vec![frame.views, frame.height, frame.width]));
    }
    let views = tensors
        .iter()
        .map(|(name, bytes, shape)| Ok((name.clone(), TensorView::new(Dtype::F32, shape.clone(), bytes)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
    let metadata = HashMap::from([("format".to_string(), "raypatch-frame/1".to_string())]);
    let bytes = safetensors::serialize(views, Some(metadata))?;
    write_atomic(path, &bytes)
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn write_pngs(dir: &Path, frame: &Frame) -> Result<()> {
    let pixels = frame.height * frame.width;
    for v in 0..frame.views {
        let rgb: Vec<u8> = frame.rgb[v * pixels * 3..(v + 1) * pixels * 3]
            .iter()
            .map(|&x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        let img = image::RgbImage::from_raw(frame.width as u32, frame.height as u32, rgb).context("image size")?;
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
        write_atomic(&dir.join(format!("view_{v:03}.png")), &png)?;
    }
    Ok(())
}
