//! render-frame: render novel views of a scene with an SRT or RP-SRT model, from the shell.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use raypatch::{
    metrics, AdapterChoice, Camera, Engine, EngineOptions, Image, OpTimes, Output, Outputs, Region, Request, SceneData,
    SceneSource,
};
use safetensors::tensor::TensorView;
use safetensors::Dtype;

/// The bundled model and scene rendered when none is given (see docs/QUALITY.md), embedded in the binary so
/// that it renders them wherever it is installed.
const DEFAULT_MODEL: (&str, &[u8]) = (
    "assets/models/fitted_scene-2000000_rpsrt_k4.safetensors",
    include_bytes!("../../../assets/models/fitted_scene-2000000_rpsrt_k4.safetensors"),
);
const DEFAULT_SCENE: (&str, &[u8]) =
    ("assets/scenes/scene-2000000.safetensors", include_bytes!("../../../assets/scenes/scene-2000000.safetensors"));
const DEFAULT_OUT: &str = "render.png";
/// Most renders one run makes (turntable frames, repeats): each takes at least milliseconds of GPU time.
const MAX_RENDERS: usize = 100_000;

#[derive(Parser, Debug)]
#[command(
    name = "render-frame",
    version,
    about = "Render novel views of a scene with an SRT / RP-SRT model on the GPU",
    after_help = "With no arguments, renders target view 0 of the bundled scene with the bundled model into render.png."
)]
struct Args {
    /// Model file (safetensors with the official key names and the config in its metadata) [default: the
    /// bundled assets/models/fitted_scene-2000000_rpsrt_k4.safetensors (fitted to the bundled scene), built into this binary].
    #[arg(long, value_name = "FILE")]
    model: Option<PathBuf>,
    /// Scene: a scene safetensors file (docs/FORMATS.md), or a folder of PNGs with a NeRF-style transforms.json
    /// [default: the bundled assets/scenes/scene-2000000.safetensors, built into this binary].
    #[arg(long, value_name = "PATH")]
    scene: Option<PathBuf>,
    /// Input views to encode: comma-separated indices or `all` [default: all of a scene file's inputs; for a
    /// folder, every frame that is not a --view target].
    #[arg(long, value_name = "LIST")]
    input_views: Option<String>,
    /// Target views to render: comma-separated indices or `all` [default: 0 for a scene file, the last frame
    /// for a folder].
    #[arg(long, value_name = "LIST")]
    view: Option<String>,
    /// Render the first target camera turned by DEG degrees about the world z axis (a novel view).
    #[arg(long, value_name = "DEG", allow_hyphen_values = true, conflicts_with = "pose")]
    orbit: Option<f64>,
    /// Render from the camera in FILE: JSON with a 4x4 camera-to-world `transform_matrix` (NeRF axes) and
    /// optional intrinsics (`camera_angle_x` or `fl_x`/`fl_y`/`cx`/`cy`, `w`/`h`).
    #[arg(long, value_name = "FILE")]
    pose: Option<PathBuf>,
    /// Render a turntable of N frames (360/N degrees apart, about the world z axis) of the first target camera.
    #[arg(long, value_name = "N", conflicts_with = "pose", value_parser = parse_count)]
    orbit_frames: Option<usize>,
    /// Where to write PNGs: a `.png` file (several images become NAME_000.png, ...), or a folder: a name
    /// without extension or an existing folder (view_000.png per target view, frame_000.png per turntable
    /// frame, render.png for one novel view).
    #[arg(long, default_value = DEFAULT_OUT)]
    out: PathBuf,
    /// `.safetensors` file to write the raw outputs into, each as a tensor of its name: `rgb` [T,H,W,3] f32
    /// after the sigmoid, `logdepth` [T,H,W].
    #[arg(long, value_name = "FILE")]
    out_raw: Option<PathBuf>,
    /// The outputs to compute, comma-separated: `rgb` (always, for the PNGs), `logdepth` (models with 4
    /// output channels; written into --out-raw).
    #[arg(long, value_name = "LIST", default_value = "rgb", value_parser = parse_outputs)]
    outputs: Outputs,
    /// Short for `--outputs rgb,logdepth`.
    #[arg(long, requires = "out_raw")]
    logdepth: bool,
    /// Print PSNR and SSIM of each target view against the scene's target images, and their means.
    #[arg(long)]
    metrics: bool,
    /// Render only this region (pixels; X,Y = top-left corner): only the patches it needs are computed.
    #[arg(long, value_name = "X,Y,W,H", value_parser = parse_region)]
    region: Option<Region>,
    /// Adapter to use: the first whose name contains this text (default: a real GPU, else lavapipe).
    #[arg(long)]
    adapter: Option<String>,
    /// List the adapters and exit.
    #[arg(long)]
    list_adapters: bool,
    /// Largest GPU buffer to use, in MiB (default: the adapter's limit); larger renders run in row bands.
    #[arg(long, value_name = "MIB", value_parser = clap::value_parser!(u64).range(1..=MAX_BUFFER_MIB))]
    max_buffer_mib: Option<u64>,
    /// Print load, encode and render times and the planned peak GPU memory.
    #[arg(long)]
    timings: bool,
    /// Render this many times more after the first render and report the median (with --timings).
    #[arg(long, default_value_t = 0, value_parser = parse_count)]
    repeat: usize,
    /// Time every op of the encode and render plans (run one by one) and print the slowest.
    #[arg(long)]
    profile: bool,
}

/// Largest --max-buffer-mib (1 TiB): above any adapter's binding limit.
const MAX_BUFFER_MIB: u64 = 1 << 20;

/// A count of renders, 0 to [`MAX_RENDERS`].
fn parse_count(text: &str) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if n <= MAX_RENDERS => Ok(n),
        _ => Err(format!("expected a whole number from 0 to {MAX_RENDERS}")),
    }
}

fn parse_outputs(text: &str) -> Result<Outputs, String> {
    let names = || Output::ALL.iter().map(|o| o.name()).collect::<Vec<_>>().join(", ");
    text.split(',').try_fold(Outputs::NONE, |set, name| match Output::from_name(name.trim()) {
        Some(output) => Ok(set.with(output)),
        None => Err(format!("unknown output {name:?}: expected a comma-separated list of {}", names())),
    })
}

fn parse_region(text: &str) -> Result<Region, String> {
    let parts: Vec<usize> = text
        .split(',')
        .map(|p| p.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{text:?} is not X,Y,W,H (four non-negative integers)"))?;
    match parts[..] {
        [x, y, width, height] if width > 0 && height > 0 => Ok(Region { x, y, width, height }),
        [_, _, _, _] => Err(format!("{text:?}: width and height must be positive")),
        _ => Err(format!("{text:?} is not X,Y,W,H (four non-negative integers)")),
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let too_large = e.chain().any(|c| {
                matches!(
                    c.downcast_ref(),
                    Some(raypatch::Error::Engine(raypatch::raypatch_engine::EngineError::TooLarge { .. }))
                )
            });
            match args.max_buffer_mib.filter(|_| too_large) {
                Some(mib) => eprintln!("render-frame: error: --max-buffer-mib {mib}: {}", one_line(&e)),
                None => eprintln!("render-frame: error: {}", one_line(&e)),
            }
            ExitCode::from(2)
        }
    }
}

/// The error and its causes on one line, leaving out causes that an outer message already quotes.
fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string().replace('\n', " ");
        if !line.contains(&text) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&text);
        }
    }
    line
}

/// Indices picked by `--FLAG LIST` among `count` items (`all`, or comma-separated indices).
fn pick(flag: &str, list: &str, count: usize, what: &str) -> Result<Vec<usize>> {
    if list.trim() == "all" {
        return Ok((0..count).collect());
    }
    let mut picked = Vec::new();
    for part in list.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let i: usize = part.parse().with_context(|| format!("--{flag} {list:?}: {part:?} is not an index or `all`"))?;
        if i >= count {
            bail!("--{flag} {i}: the scene has {count} {what} (0 to {})", count.saturating_sub(1));
        }
        picked.push(i);
    }
    if picked.is_empty() {
        bail!("--{flag} {list:?}: no {what} selected");
    }
    Ok(picked)
}

/// One image to render and where its PNG goes.
struct Shot {
    camera: Camera,
    /// The target view's ground truth, for --metrics.
    truth: Option<Image>,
    label: String,
    png: PathBuf,
}

fn run(args: &Args) -> Result<()> {
    if args.list_adapters {
        for (i, adapter) in Engine::adapters().iter().enumerate() {
            println!("{adapter}{}", if i == 0 { "  [default]" } else { "" });
        }
        return Ok(());
    }
    let adapter = args.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
    let max_buffer_bytes = args.max_buffer_mib.map(|mib| mib << 20);
    let engine = Engine::new(EngineOptions { adapter, max_buffer_bytes }).context("--adapter")?;
    let start = Instant::now();
    let model = match &args.model {
        Some(path) => engine.load(path)?,
        None => engine.load_bytes(DEFAULT_MODEL.0, DEFAULT_MODEL.1)?,
    };
    let load_time = start.elapsed();
    let data = match &args.scene {
        Some(path) => SceneData::load(path)?,
        None => SceneData::from_bytes(DEFAULT_SCENE.0, DEFAULT_SCENE.1)?,
    };
    let scene_path = args.scene.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_SCENE.0));

    let frames = matches!(data.source, SceneSource::Frames(_));
    let default_view = if frames { data.targets.len() - 1 } else { 0 };
    let views = match &args.view {
        Some(list) => pick("view", list, data.targets.len(), "target views")?,
        None => vec![default_view],
    };
    let inputs = match &args.input_views {
        Some(list) => pick("input-views", list, data.inputs.len(), "input views")?,
        None if frames => (0..data.inputs.len()).filter(|i| !views.contains(i)).collect(),
        None => (0..data.inputs.len()).collect(),
    };
    if inputs.is_empty() {
        bail!(
            "{}: no input view left to encode (every frame is a target; choose inputs with --input-views)",
            scene_path.display()
        );
    }
    let inputs: Vec<_> = inputs.iter().map(|&i| data.inputs[i].clone()).collect();
    let shots = shots(args, &data, &views)?;
    let output_files = check_outputs(args, &shots, &data)?;
    let mut warnings = model.check_inputs(&inputs)?;
    for shot in &shots {
        warnings.extend(model.check_camera(&shot.camera).with_context(|| shot.label.clone())?);
    }
    warnings.dedup();
    for warning in &warnings {
        eprintln!("render-frame: warning: {warning}");
    }
    if args.metrics && shots.iter().any(|s| s.truth.is_none()) {
        bail!(
            "--metrics: needs target views with ground-truth images (scene `target_images`, or frames), \
             not --orbit, --orbit-frames or --pose"
        );
    }
    let mut outputs = args.outputs.with(Output::Rgb);
    if args.logdepth {
        outputs = outputs.with(Output::LogDepth);
    }
    if args.out_raw.is_none() {
        if let Some(extra) = outputs.without(Output::Rgb).iter().next() {
            bail!("--outputs {}: only --out-raw FILE writes it", extra.name());
        }
    }
    let request = Request { outputs, region: args.region };

    let start = Instant::now();
    let scene = model.encode(&inputs)?;
    let encode_time = start.elapsed();
    // Check every camera against the model and the request (this builds the render plans) before touching
    // any output.
    let start = Instant::now();
    for shot in &shots {
        scene.render_stats(&shot.camera, &request).with_context(|| shot.label.clone())?;
    }
    let plan_time = start.elapsed();
    let progress = if args.orbit_frames.is_some() {
        let bar = ProgressBar::new(shots.len() as u64);
        bar.set_style(
            ProgressStyle::with_template("{bar:40} {pos}/{len} frames, {elapsed} (eta {eta})").expect("template"),
        );
        bar
    } else {
        ProgressBar::hidden()
    };
    let mut rendered = Vec::with_capacity(shots.len());
    let mut render_times = Vec::with_capacity(shots.len());
    for shot in &shots {
        let start = Instant::now();
        rendered.push(scene.render(&shot.camera, &request).with_context(|| shot.label.clone())?);
        render_times.push(start.elapsed());
        progress.inc(1);
    }
    progress.finish_and_clear();
    let mut repeats = Vec::with_capacity(args.repeat);
    for _ in 0..args.repeat {
        let start = Instant::now();
        scene.render(&shots[0].camera, &request)?;
        repeats.push(start.elapsed());
    }

    let images: Vec<Image> = rendered.iter().map(|r| r.rgb().expect("rgb is always requested")).collect();
    let metric_lines = if args.metrics { metrics_report(&shots, &images, request.region)? } else { Vec::new() };
    let mut contents = images.iter().map(Image::encode_png).collect::<raypatch::Result<Vec<_>>>()?;
    if args.out_raw.is_some() {
        contents.push(raw_bytes(&rendered)?);
    }
    output_files.write(&contents)?;
    let written = &output_files.files;

    let k = model.patch_size();
    let first = &images[0];
    let region =
        request.region.map_or(String::new(), |r| format!(" (region x={} y={} {}x{})", r.x, r.y, r.width, r.height));
    println!(
        "rendered {} view(s) of {}x{}{region} from {} input view(s) with {} ({}, k={k}, {:.2}M parameters) on {}",
        images.len(),
        shots[0].camera.width(),
        shots[0].camera.height(),
        inputs.len(),
        model.path(),
        if k == 1 { "SRT" } else { "RP-SRT" },
        model.parameter_count() as f64 / 1e6,
        engine.adapter()
    );
    let total: Duration = render_times.iter().sum();
    println!(
        "encode {:.1} ms, render {:.1} ms ({} image(s) of {}x{}); wrote {}",
        ms(encode_time),
        ms(total),
        images.len(),
        first.width(),
        first.height(),
        written.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    );
    for line in &metric_lines {
        println!("{line}");
    }
    if args.timings {
        println!(
            "load {:.1} ms, encode {:.1} ms, render plan {:.1} ms (buffers allocated, pipelines compiled), \
             first render {:.1} ms",
            ms(load_time),
            ms(encode_time),
            ms(plan_time),
            ms(render_times[0])
        );
        if render_times.len() > 1 {
            println!("later renders: {}", summary(&render_times[1..]));
        }
        if !repeats.is_empty() {
            println!("repeated render: {}", summary(&repeats));
        }
        let stats = scene.render_stats(&shots[0].camera, &request)?;
        let mib = |b: u64| b as f64 / (1 << 20) as f64;
        println!(
            "planned peak GPU memory: render {:.2} MiB ({} queries, {} dispatches), encode {:.2} MiB; weights {:.2} MiB; scene cache {:.2} MiB",
            mib(stats.peak_bytes),
            stats.queries,
            stats.dispatches,
            mib(scene.encode_peak_bytes()),
            mib(model.weight_bytes()),
            mib(scene.cache_bytes())
        );
    }
    if args.profile {
        print_profile("encode", &model.profile_encode(&inputs)?);
        print_profile("render", &scene.profile_render(&shots[0].camera, &request)?);
    }
    // On stderr, after the run, so that a failing run still prints exactly one line.
    let adapter = engine.adapter_details();
    if !adapter.is_gpu() {
        eprintln!(
            "render-frame: note: ran on {} ({} adapter, {} backend), not a GPU: rendering is slow \
             (--list-adapters shows what wgpu found)",
            adapter.name, adapter.kind, adapter.backend
        );
    }
    Ok(())
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// "median M ms, min A ms, max B ms over N runs".
fn summary(times: &[Duration]) -> String {
    let mut sorted = times.to_vec();
    sorted.sort();
    format!(
        "median {:.1} ms, min {:.1} ms, max {:.1} ms over {} runs",
        ms(sorted[sorted.len() / 2]),
        ms(sorted[0]),
        ms(sorted[sorted.len() - 1]),
        sorted.len()
    )
}

/// The images to render: the chosen target views, or novel cameras made from the first of them.
fn shots(args: &Args, data: &SceneData, views: &[usize]) -> Result<Vec<Shot>> {
    let folder = match args.out.extension() {
        Some(e) if e.eq_ignore_ascii_case("png") => false,
        Some(_) if !args.out.is_dir() => bail!(
            "--out {}: expected a .png file, or a folder (a name without extension, or an existing folder)",
            args.out.display()
        ),
        _ => true,
    };
    let reference = &data.targets[views[0]].camera;
    if let Some(degrees) = args.orbit.filter(|d| !d.is_finite()) {
        bail!("--orbit {degrees}: expected a finite angle in degrees");
    }
    let novel = |camera: Camera, label: String| Shot { camera, truth: None, label, png: PathBuf::new() };
    let (mut shots, folder_names): (Vec<Shot>, Vec<String>) = if let Some(path) = &args.pose {
        (
            vec![novel(raypatch::load_pose(path, reference)?, format!("--pose {}", path.display()))],
            vec!["render".into()],
        )
    } else if let Some(n) = args.orbit_frames {
        if n == 0 {
            bail!("--orbit-frames 0: expected at least one frame");
        }
        let start = args.orbit.unwrap_or(0.0);
        let turn = |i: usize| start + 360.0 * i as f64 / n as f64;
        let shots = (0..n).map(|i| novel(reference.orbited(turn(i)), format!("turntable frame {i} ({:.1}°)", turn(i))));
        (shots.collect(), (0..n).map(|i| format!("frame_{i:03}")).collect())
    } else if let Some(degrees) = args.orbit {
        (vec![novel(reference.orbited(degrees), format!("--orbit {degrees}"))], vec!["render".into()])
    } else {
        let shots = views.iter().map(|&v| Shot {
            camera: data.targets[v].camera.clone(),
            truth: data.targets[v].image.clone(),
            label: format!("target view {v}"),
            png: PathBuf::new(),
        });
        (shots.collect(), views.iter().map(|v| format!("view_{v:03}")).collect())
    };
    let single = shots.len() == 1;
    for (i, (shot, name)) in shots.iter_mut().zip(folder_names).enumerate() {
        shot.png = if folder {
            args.out.join(format!("{name}.png"))
        } else if single {
            args.out.clone()
        } else {
            let stem = args.out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            args.out.with_file_name(format!("{stem}_{i:03}.png"))
        };
    }
    Ok(shots)
}

/// The files a run writes (PNGs, then the raw outputs), checked before any GPU work, written all or none.
struct OutputFiles {
    files: Vec<PathBuf>,
    /// An --out folder to create when writing, and to remove again if the writes fail.
    new_folder: Option<PathBuf>,
}

impl OutputFiles {
    fn write(&self, contents: &[Vec<u8>]) -> Result<()> {
        if let Some(folder) = &self.new_folder {
            std::fs::create_dir(folder)
                .with_context(|| format!("--out {}: cannot create the folder", folder.display()))?;
        }
        let files: Vec<(&Path, &[u8])> =
            self.files.iter().map(PathBuf::as_path).zip(contents.iter().map(Vec::as_slice)).collect();
        let written = raypatch::write_all_atomic(&files);
        if let (Err(_), Some(folder)) = (&written, &self.new_folder) {
            let _ = std::fs::remove_dir(folder);
        }
        Ok(written?)
    }
}

/// Where a path points, for comparing outputs with each other and with the inputs: the canonical folder
/// joined with the file name (the file itself may not exist yet).
fn identity(path: &Path) -> PathBuf {
    let folder = raypatch::folder_of(path);
    let folder = folder.canonicalize().unwrap_or_else(|_| folder.to_path_buf());
    folder.join(path.file_name().unwrap_or_default())
}

/// Fails before any GPU work when an output cannot be written: its folder must exist (or be creatable, for
/// an --out folder), anything already at its path must be a regular file, and no output may be another
/// output or one of the inputs.
fn check_outputs(args: &Args, shots: &[Shot], data: &SceneData) -> Result<OutputFiles> {
    let mut named: Vec<(&str, PathBuf)> = shots.iter().map(|s| ("--out", s.png.clone())).collect();
    if let Some(path) = &args.out_raw {
        if path.extension().is_none_or(|e| !e.eq_ignore_ascii_case("safetensors")) {
            bail!("--out-raw {}: expected a file name ending in .safetensors", path.display());
        }
        named.push(("--out-raw", path.clone()));
    }
    let out_is_folder = shots.iter().any(|s| s.png.parent() == Some(args.out.as_path()));
    let new_folder = (out_is_folder && !args.out.exists()).then(|| args.out.clone());
    if let Some(folder) = &new_folder {
        let parent = raypatch::folder_of(folder);
        if !parent.is_dir() {
            bail!("--out {}: cannot create the folder: {} is not a folder", folder.display(), parent.display());
        }
    }
    let mut inputs: Vec<(String, PathBuf)> = data.files.iter().map(|f| ("--scene".to_string(), identity(f))).collect();
    for (flag, path) in [("--model", &args.model), ("--pose", &args.pose)] {
        if let Some(path) = path {
            inputs.push((flag.to_string(), identity(path)));
        }
    }
    let mut seen: Vec<(&str, PathBuf)> = Vec::new();
    for (flag, path) in &named {
        let id = identity(path);
        if let Some((other, _)) = seen.iter().find(|(_, p)| *p == id) {
            bail!("{flag} {}: the same file as an output of {other}", path.display());
        }
        if let Some((input, _)) = inputs.iter().find(|(_, p)| *p == id) {
            bail!("{flag} {}: would overwrite the input given by {input}", path.display());
        }
        if new_folder.as_deref() != path.parent() {
            raypatch::check_output_path(path).with_context(|| flag.to_string())?;
        } else if std::fs::symlink_metadata(path).is_ok() {
            bail!("{flag} {}: exists", path.display());
        }
        seen.push((flag, id));
    }
    Ok(OutputFiles { files: named.into_iter().map(|(_, p)| p).collect(), new_folder })
}

/// PSNR and SSIM of each rendered view against its ground truth (cropped to the region), and their means.
fn metrics_report(shots: &[Shot], images: &[Image], region: Option<Region>) -> Result<Vec<String>> {
    let mut lines = Vec::new();
    let (mut psnr_sum, mut ssim_sum) = (0.0, 0.0);
    for (shot, image) in shots.iter().zip(images) {
        let truth = shot.truth.as_ref().expect("checked before rendering");
        let truth = match region {
            Some(r) => truth.crop(r)?,
            None => truth.clone(),
        };
        let (p, s) = (
            metrics::psnr(image, &truth)?,
            metrics::ssim(image, &truth).with_context(|| format!("--metrics: {}", shot.label))?,
        );
        lines.push(format!("{}: PSNR {p:.3} dB, SSIM {s:.4}", shot.label));
        psnr_sum += p;
        ssim_sum += s;
    }
    let n = shots.len() as f64;
    lines.push(format!("mean over {} view(s): PSNR {:.3} dB, SSIM {:.4}", shots.len(), psnr_sum / n, ssim_sum / n));
    Ok(lines)
}

/// The slowest ops of a plan, with their share of the plan's total.
fn print_profile(what: &str, ops: &OpTimes) {
    let total: f64 = ops.iter().map(|(_, t)| t.as_secs_f64()).sum();
    println!("{what}: {} ops, {:.1} ms run one by one; slowest:", ops.len(), total * 1e3);
    let mut sorted: Vec<_> = ops.iter().collect();
    sorted.sort_by_key(|(_, t)| std::cmp::Reverse(*t));
    for (label, t) in sorted.iter().take(12) {
        println!("  {:8.2} ms {:5.1}%  {label}", ms(*t), 100.0 * t.as_secs_f64() / total);
    }
}

/// A safetensors file with one tensor per output, named by the output: `[T,H,W,channels]`, or `[T,H,W]` for
/// one channel.
fn raw_bytes(rendered: &[raypatch::Rendered]) -> Result<Vec<u8>> {
    let region = rendered[0].region;
    let tensors: Vec<(String, Vec<u8>, Vec<usize>)> = rendered[0]
        .outputs
        .iter()
        .map(|first| {
            let values = rendered.iter().flat_map(|r| r.get(first.output).unwrap_or_default().iter().copied());
            let mut shape = vec![rendered.len(), region.height, region.width, first.channels];
            if first.channels == 1 {
                shape.pop();
            }
            (first.output.name().to_string(), f32_bytes(values), shape)
        })
        .collect();
    let views = tensors
        .iter()
        .map(|(name, bytes, shape)| Ok((name.clone(), TensorView::new(Dtype::F32, shape.clone(), bytes)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
    let metadata = HashMap::from([("format".to_string(), "raypatch-frame/1".to_string())]);
    Ok(safetensors::serialize(views, Some(metadata))?)
}

fn f32_bytes(values: impl Iterator<Item = f32>) -> Vec<u8> {
    values.flat_map(|v| v.to_le_bytes()).collect()
}
