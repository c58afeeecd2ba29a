//! render-frame: render novel views, depth and object masks of a scene with an SRT, RP-SRT, OSRT or RP-OSRT
//! model (and DeFiNe), from the shell.

mod files;
mod parse;
mod report;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use raypatch::{
    AdapterChoice, Camera, Engine, EngineOptions, Image, MatmulKernel, Output, Outputs, Region, Request, SceneData,
    SceneSource,
};

use files::{is_folder, png_paths, raw_bytes, OutputFiles};
use parse::{parse_count, parse_depth_range, parse_fps, parse_outputs, parse_region};
use report::{ms, print_profile, summary, Truth};

/// The bundled model and scene rendered when none is given (see docs/QUALITY.md), embedded in the binary so
/// that it renders them wherever it is installed.
const DEFAULT_MODEL: (&str, &[u8]) = (
    "assets/models/fitted_scene-2000000_rpsrt_k4.safetensors",
    include_bytes!("../../../assets/models/fitted_scene-2000000_rpsrt_k4.safetensors"),
);
const DEFAULT_SCENE: (&str, &[u8]) =
    ("assets/scenes/scene-2000000.safetensors", include_bytes!("../../../assets/scenes/scene-2000000.safetensors"));
const DEFAULT_OUT: &str = "render.png";

#[derive(Parser, Debug)]
#[command(
    name = "render-frame",
    version,
    about = "Render novel views, depth and object masks of a scene with an SRT, OSRT or DeFiNe model (or its Ray-Patch variant) on the GPU",
    after_help = "With no arguments, renders target view 0 of the bundled scene with the bundled model into render.png. \
                  `render-frame --serve` serves a live viewer in the browser (its flags: `render-frame --serve --help`)."
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
    /// Render every camera of a camera path: nerfstudio's camera_path.json (`render_width`/`render_height`,
    /// `camera_path` of `camera_to_world` and vertical `fov`; perspective only) or raypatch's form (`width`,
    /// `height`, `frames`); frame_000.png, ... into the --out folder (README, "Camera paths").
    #[arg(long, value_name = "FILE", conflicts_with_all = ["pose", "orbit", "orbit_frames", "view"])]
    camera_path: Option<PathBuf>,
    /// Frames per second of an animated `--out NAME.gif` [default: the camera path's `fps`, else 24].
    #[arg(long, value_name = "F", value_parser = parse_fps)]
    fps: Option<f64>,
    /// Where to write PNGs: a `.png` file (several images become NAME_000.png, ...), or a folder: a name
    /// without extension or an existing folder (view_000.png per target view, frame_000.png per turntable
    /// frame, render.png for one novel view); or a `.gif` file: every image as a frame of one animation.
    #[arg(long, default_value = DEFAULT_OUT)]
    out: PathBuf,
    /// `.safetensors` file to write the raw outputs into, each as a tensor of its name: `rgb` [T,H,W,3] f32
    /// after the sigmoid, `logdepth` and `depth` [T,H,W], `segmentation` [T,H,W,slots].
    #[arg(long, value_name = "FILE")]
    out_raw: Option<PathBuf>,
    /// The outputs to compute, comma-separated: `rgb` (PNGs to --out), `segmentation` (OSRT models: the
    /// slot weights, to --segmentation or --out-raw), `logdepth` and `depth` = exp(logdepth) (models with a
    /// depth channel, to --out-raw). Only these are computed: without rgb no colour is decoded.
    #[arg(long, value_name = "LIST", default_value = "rgb", value_parser = parse_outputs)]
    outputs: Outputs,
    /// Short for adding `logdepth` to --outputs.
    #[arg(long, requires = "out_raw")]
    logdepth: bool,
    /// Write object masks (OSRT models): per view, each pixel coloured by its most-weighted slot, into a `.png`
    /// file or a folder as --out does. Adds `segmentation` to --outputs.
    #[arg(long, value_name = "DIR|FILE.png")]
    segmentation: Option<PathBuf>,
    /// Write depth pictures (models with a depth channel): per view, depth = exp(logdepth) coloured with the
    /// turbo map (near red, far blue, no depth black) above a colour bar with its range in metres, into a
    /// `.png` file or a folder as --out does. Adds `depth` to --outputs.
    #[arg(long, value_name = "DIR|FILE.png")]
    depth: Option<PathBuf>,
    /// The depth range the --depth colours span, in metres [default: each view's own minimum and maximum].
    #[arg(long, value_name = "MIN,MAX", requires = "depth", value_parser = parse_depth_range)]
    depth_range: Option<(f32, f32)>,
    /// Print each target view's PSNR and SSIM against the scene's target images, for OSRT models the FG-ARI of
    /// the segmentation against the scene's `target_masks`, and for depth models Abs.Rel, Sq.Rel and RMSE of
    /// the depth against the scene's `target_depth` (each computed then), with their means and pooled figures.
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
    /// The kernel of the linear layers (default: the adapter's fastest: `lanes` on lavapipe, `tiled` on GPUs).
    #[arg(long, value_name = "KERNEL", value_parser = PossibleValuesParser::new(MatmulKernel::ALL.map(MatmulKernel::name))
        .map(|name: String| MatmulKernel::from_name(&name).unwrap_or_default()))]
    matmul_kernel: Option<MatmulKernel>,
    /// Print load, encode and render times, the planned peak GPU memory, and the time spent compiling GPU
    /// pipelines with the pipeline cache file used (set RAYPATCH_CACHE_DIR to move it, or to `off`).
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

fn main() -> ExitCode {
    if raypatch_viewer::requested() {
        return raypatch_viewer::main(DEFAULT_MODEL, DEFAULT_SCENE);
    }
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

/// One image to render, and its name in an output folder.
struct Shot {
    camera: Camera,
    /// The target view's ground truth, for --metrics.
    truth: Option<Image>,
    /// The target view's object ids, for --metrics (FG-ARI).
    masks: Option<Vec<u32>>,
    /// The target view's depth in metres, for --metrics (Abs.Rel, Sq.Rel, RMSE).
    depth: Option<Vec<f32>>,
    label: String,
    name: String,
}

impl Shot {
    /// A camera without ground truth (a novel view).
    fn novel(camera: Camera, label: String, name: String) -> Shot {
        Shot { camera, truth: None, masks: None, depth: None, label, name }
    }
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
    let matmul = args.matmul_kernel;
    let context = if matmul.is_some() { "--adapter / --matmul-kernel" } else { "--adapter" };
    let engine =
        Engine::new(EngineOptions { adapter, max_buffer_bytes, matmul, ..Default::default() }).context(context)?;
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
    data.check_rays(model.ray_kind())?;

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
    // A camera path's frames, with its frame rate; else the views, turntable or pose asked for.
    let (shots, path_fps) = match &args.camera_path {
        Some(path) => {
            let path = raypatch::load_camera_path(path)?;
            let shots = (path.cameras.into_iter().enumerate())
                .map(|(i, camera)| Shot::novel(camera, format!("camera path frame {i}"), format!("frame_{i:03}")))
                .collect();
            (shots, path.fps)
        }
        None => (shots(args, &data, &views)?, None),
    };
    let outputs = requested_outputs(args, &shots, model.outputs())?;
    let output_files = output_files(args, &shots, &data, outputs)?;
    let mut warnings = model.check_inputs(&inputs)?;
    for shot in &shots {
        warnings.extend(model.check_camera(&shot.camera).with_context(|| shot.label.clone())?);
    }
    warnings.dedup();
    for warning in &warnings {
        eprintln!("render-frame: warning: {warning}");
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
    let progress = if args.orbit_frames.is_some() || args.camera_path.is_some() {
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

    let metric_lines = if args.metrics {
        let truths: Vec<Truth> = shots
            .iter()
            .map(|s| Truth {
                label: &s.label,
                image: s.truth.as_ref(),
                masks: s.masks.as_deref(),
                depth: s.depth.as_deref(),
            })
            .collect();
        report::metrics(&truths, &rendered, shots[0].camera.width())?
    } else {
        Vec::new()
    };
    let images: Vec<Image> = rendered.iter().filter_map(raypatch::Rendered::rgb).collect();
    let mut contents = if is_gif(&args.out) {
        let fps = args.fps.unwrap_or_else(|| path_fps.unwrap_or(DEFAULT_FPS).clamp(1.0, 100.0));
        vec![Image::encode_gif(&images, fps)?]
    } else {
        images.iter().map(Image::encode_png).collect::<raypatch::Result<Vec<_>>>()?
    };
    if args.segmentation.is_some() {
        for r in &rendered {
            let (weights, slots) = r.segmentation().expect("segmentation was requested");
            contents.push(Image::from_segmentation(r.region.width, r.region.height, weights, slots)?.encode_png()?);
        }
    }
    if args.depth.is_some() {
        for r in &rendered {
            let depth = r.depth().expect("depth was requested");
            let picture = Image::from_depth(r.region.width, r.region.height, depth, args.depth_range)?;
            contents.push(picture.encode_png()?);
        }
    }
    if args.out_raw.is_some() {
        contents.push(raw_bytes(&rendered)?);
    }
    output_files.write(&contents)?;

    let k = model.patch_size();
    let region = rendered[0].region;
    let region_text =
        args.region.map_or(String::new(), |r| format!(" (region x={} y={} {}x{})", r.x, r.y, r.width, r.height));
    let family = model.config().name();
    println!(
        "rendered {} view(s) of {}x{}{region_text} ({}) from {} input view(s) with {} ({family}, k={k}, {:.2}M parameters) on {}",
        rendered.len(),
        shots[0].camera.width(),
        shots[0].camera.height(),
        outputs.iter().map(Output::name).collect::<Vec<_>>().join(", "),
        inputs.len(),
        model.path(),
        model.parameter_count() as f64 / 1e6,
        engine.adapter()
    );
    let total: Duration = render_times.iter().sum();
    println!(
        "encode {:.1} ms, render {:.1} ms ({} image(s) of {}x{}); wrote {}",
        ms(encode_time),
        ms(total),
        rendered.len(),
        region.width,
        region.height,
        output_files.paths().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
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
        println!("{}", report::pipelines(&engine.counters(), &engine.pipeline_cache()));
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

/// The images to render: the chosen target views, or novel cameras made from the first of them.
fn shots(args: &Args, data: &SceneData, views: &[usize]) -> Result<Vec<Shot>> {
    let reference = &data.targets[views[0]].camera;
    if let Some(degrees) = args.orbit.filter(|d| !d.is_finite()) {
        bail!("--orbit {degrees}: expected a finite angle in degrees");
    }
    if let Some(path) = &args.pose {
        let camera = raypatch::load_pose(path, reference)?;
        Ok(vec![Shot::novel(camera, format!("--pose {}", path.display()), "render".into())])
    } else if let Some(n) = args.orbit_frames {
        if n == 0 {
            bail!("--orbit-frames 0: expected at least one frame");
        }
        let start = args.orbit.unwrap_or(0.0);
        let turn = |i: usize| start + 360.0 * i as f64 / n as f64;
        Ok((0..n)
            .map(|i| {
                let label = format!("turntable frame {i} ({:.1}°)", turn(i));
                Shot::novel(reference.orbited(turn(i)), label, format!("frame_{i:03}"))
            })
            .collect())
    } else if let Some(degrees) = args.orbit {
        Ok(vec![Shot::novel(reference.orbited(degrees), format!("--orbit {degrees}"), "render".into())])
    } else {
        Ok(views
            .iter()
            .map(|&v| Shot {
                camera: data.targets[v].camera.clone(),
                truth: data.targets[v].image.clone(),
                masks: data.targets[v].masks.clone(),
                depth: data.targets[v].depth.clone(),
                label: format!("target view {v}"),
                name: format!("view_{v:03}"),
            })
            .collect())
    }
}

/// The outputs to compute: --outputs, with what --logdepth, --segmentation, --depth and --metrics imply; each
/// must be one the model renders and have somewhere to go.
fn requested_outputs(args: &Args, shots: &[Shot], model_outputs: Outputs) -> Result<Outputs> {
    let mut outputs = args.outputs;
    if args.logdepth {
        outputs = outputs.with(Output::LogDepth);
    }
    if args.segmentation.is_some() {
        outputs = outputs.with(Output::Segmentation);
    }
    if args.depth.is_some() {
        outputs = outputs.with(Output::Depth);
    }
    let flag = |o: Output| match o {
        Output::Segmentation if args.segmentation.is_some() => "--segmentation".to_string(),
        Output::Depth if args.depth.is_some() => "--depth".to_string(),
        Output::LogDepth if args.logdepth => "--logdepth".to_string(),
        o => format!("--outputs {}", o.name()),
    };
    if let Some(missing) = outputs.missing_from(model_outputs).next() {
        let names: Vec<&str> = model_outputs.iter().map(Output::name).collect();
        bail!(
            "{}: {} was requested but this model has {} (it renders {})",
            flag(missing),
            missing.title(),
            missing.lacked(),
            names.join(", ")
        );
    }
    let depth_truth = shots.iter().all(|s| s.depth.is_some());
    if args.metrics {
        let masks = shots.iter().all(|s| s.masks.is_some());
        if masks && model_outputs.contains(Output::Segmentation) {
            outputs = outputs.with(Output::Segmentation);
        }
        if depth_truth && model_outputs.contains(Output::Depth) {
            outputs = outputs.with(Output::Depth);
        }
        let images = outputs.contains(Output::Rgb) && shots.iter().all(|s| s.truth.is_some());
        let objects = masks && outputs.contains(Output::Segmentation);
        let depths = depth_truth && outputs.contains(Output::Depth);
        if !images && !objects && !depths {
            bail!(
                "--metrics: needs target views with ground truth: ground-truth images (scene `target_images`, or \
                 frames) for rgb, `target_masks` for an OSRT model's segmentation, or `target_depth` (frames: \
                 `depth_file_path`) for a depth model; not --orbit, --orbit-frames, --pose or --camera-path"
            );
        }
    }
    for output in outputs.iter() {
        let (written, writers) = match output {
            Output::Rgb => (true, ""),
            Output::Segmentation => (
                args.segmentation.is_some() || args.out_raw.is_some() || args.metrics,
                "--segmentation DIR|FILE.png or --out-raw FILE",
            ),
            Output::Depth => (
                args.depth.is_some() || args.out_raw.is_some() || (args.metrics && depth_truth),
                "--depth DIR|FILE.png or --out-raw FILE",
            ),
            Output::LogDepth => (args.out_raw.is_some(), "--out-raw FILE"),
        };
        if !written {
            bail!("{}: nothing would write it (add {writers})", flag(output));
        }
    }
    if outputs.is_empty() {
        bail!("--outputs: nothing to compute");
    }
    Ok(outputs)
}

/// The files the run writes (rgb PNGs, segmentation PNGs, depth PNGs, the raw outputs), checked before any GPU
/// work.
/// Frames per second of an animated GIF when neither --fps nor the camera path gives one.
const DEFAULT_FPS: f64 = 24.0;

/// Whether `--out` names an animated GIF.
fn is_gif(out: &Path) -> bool {
    out.extension().is_some_and(|e| e.eq_ignore_ascii_case("gif"))
}

fn output_files(args: &Args, shots: &[Shot], data: &SceneData, outputs: Outputs) -> Result<OutputFiles> {
    let names: Vec<String> = shots.iter().map(|s| s.name.clone()).collect();
    let mut files: Vec<(&'static str, PathBuf)> = Vec::new();
    let mut folders: Vec<(&'static str, &Path)> = Vec::new();
    if args.fps.is_some() && !is_gif(&args.out) {
        bail!("--fps: only for an animated --out NAME.gif (--out {} is not one)", args.out.display());
    }
    let gif = is_gif(&args.out);
    let png = args.out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !gif && !png && args.out.extension().is_some() && !args.out.is_dir() {
        bail!(
            "--out {}: expected a .png file, a .gif file (an animation), or a folder (a name without extension, or \
             an existing folder)",
            args.out.display()
        );
    }
    if gif {
        if !outputs.contains(Output::Rgb) {
            bail!("--out {}: an animated GIF shows the rgb output; add rgb to --outputs", args.out.display());
        }
        files.push(("--out", args.out.clone()));
    }
    let pngs = [
        (outputs.contains(Output::Rgb) && !gif, "--out", Some(&args.out)),
        (true, "--segmentation", args.segmentation.as_ref()),
        (true, "--depth", args.depth.as_ref()),
    ];
    for (wanted, flag, dest) in pngs {
        if let Some(dest) = dest.filter(|_| wanted) {
            files.extend(png_paths(flag, dest, &names)?.into_iter().map(|p| (flag, p)));
            if is_folder(flag, dest)? {
                folders.push((flag, dest));
            }
        }
    }
    if let Some(path) = &args.out_raw {
        if path.extension().is_none_or(|e| !e.eq_ignore_ascii_case("safetensors")) {
            bail!("--out-raw {}: expected a file name ending in .safetensors", path.display());
        }
        files.push(("--out-raw", path.clone()));
    }
    let mut inputs: Vec<(&str, PathBuf)> = data.files.iter().map(|f| ("--scene", f.clone())).collect();
    for (flag, path) in [("--model", &args.model), ("--pose", &args.pose), ("--camera-path", &args.camera_path)] {
        if let Some(path) = path {
            inputs.push((flag, path.clone()));
        }
    }
    OutputFiles::check(files, &folders, &inputs)
}
