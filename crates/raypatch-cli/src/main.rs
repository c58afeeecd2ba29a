//! render-frame: render novel views, depth and object masks of a scene with an SRT, RP-SRT, OSRT or RP-OSRT
//! model (and DeFiNe), from the shell.

mod cameras;
mod files;
mod h264_lossless;
mod panels;
mod parse;
mod report;
mod sequence;
mod video;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Parser;
use raypatch::raypatch_model::error::MAX_MESSAGE_CHARS;
use raypatch::{
    AdapterChoice, Engine, EngineOptions, MatmulKernel, Output, Outputs, Precision, Region, Request, SceneData,
    SceneSource,
};

use cameras::{check_patch_size, CameraArgs, Shot};
use panels::Panel;
use parse::{
    parse_count, parse_depth_range, parse_fps, parse_mp4_mode, parse_outputs, parse_panels, parse_region, quote,
};
use report::{ms, print_profile, summary, Truth};
use sequence::Sequence;
use video::{Mp4Mode, DEFAULT_FPS};

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
    /// Model file: safetensors with the official key names and the config in its metadata, or an official
    /// Lightning .ckpt checkpoint (told apart by content) [default: the
    /// bundled assets/models/fitted_scene-2000000_rpsrt_k4.safetensors (fitted to the bundled scene), built into this binary].
    #[arg(long, value_name = "FILE")]
    model: Option<PathBuf>,
    /// Save the --model checkpoint (an official Lightning .ckpt) as a model .safetensors FILE, the file
    /// tools/conversion/convert_checkpoint.py writes, and exit without rendering (no GPU needed).
    #[arg(long, value_name = "FILE", requires = "model")]
    save_model: Option<PathBuf>,
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
    #[command(flatten)]
    cameras: CameraArgs,
    /// Frames per second of a video `--out NAME.mp4` or `NAME.gif` [default: the camera path's `fps`, else 24].
    #[arg(long, value_name = "F", value_parser = parse_fps)]
    fps: Option<f64>,
    /// Where to write the colour images: a `.png` file (several images become NAME_000.png, ...), or a folder:
    /// a name without extension or an existing folder (view_000.png per target view, frame_000.png per
    /// sequence frame, render.png for one novel view); or a video, every image a frame: `.mp4` (H.264) or
    /// `.gif` (animated).
    #[arg(long, default_value = DEFAULT_OUT)]
    out: PathBuf,
    /// How `--out NAME.mp4` is encoded: `compact`: H.264 4:2:0 from OpenH264, small, plays everywhere, close
    /// to the renders but not exact (each 2x2 pixels share one colour: small frames can fall below 40 dB PSNR);
    /// `lossless`: H.264 High 4:4:4 with every pixel stored raw, exactly the renders at any size, 3 bytes a
    /// pixel a frame, plays in ffmpeg and Chromium, not in many other players; `auto`: compact unless its first
    /// frame would be below 40 dB PSNR against the render or compact cannot encode the size (odd sides, under
    /// 16 pixels), then lossless [default: auto].
    #[arg(long, value_name = "MODE", value_parser = parse_mp4_mode)]
    mp4: Option<Mp4Mode>,
    /// Lay each --out image out side by side with labels: rgb, depth (turbo map, one range for the whole
    /// run: --depth-range, else a first pass over every frame's depth), segmentation (OSRT: masks in the fixed
    /// palette), input (the first input view); e.g. rgb,depth.
    #[arg(long, value_name = "LIST", value_parser = parse_panels)]
    panels: Option<std::vec::Vec<Panel>>,
    /// No progress bar (there is none either when stderr is not a terminal).
    #[arg(long, short)]
    quiet: bool,
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
    /// The depth range the --depth and --panels depth colours span, in metres [default: --depth: each view's
    /// own minimum and maximum; --panels: the minimum and maximum over every frame].
    #[arg(long, value_name = "MIN,MAX", value_parser = parse_depth_range)]
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
    /// `f32` (default); `f16`: linear weights stored as f16; `f16-act`: the tensor path: every GEMM (linear layers,
    /// convolutions, attention) on cooperative matrices (tensor cores) where the device has them, operands rounded to
    /// f16, sums in f32 (rgb within ~1e-2; --timings says which kernels ran). f16 needs shader-f16.
    #[arg(long, value_name = "P", default_value = "f32", value_parser = PossibleValuesParser::new(Precision::ALL.map(Precision::name))
        .map(|name: String| Precision::from_name(&name).unwrap_or_default()))]
    precision: Precision,
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
    // First, while this is the process's only thread (setting the environment is sound then): Mesa's shader
    // cache where it can be written, or off, before any wgpu instance loads a driver (issue 50). Said by
    // --timings; the viewer started below gets the same.
    raypatch::prepare_driver_cache();
    if raypatch_viewer::requested() {
        return raypatch_viewer::main(DEFAULT_MODEL, DEFAULT_SCENE);
    }
    let args = match Args::try_parse() {
        Ok(args) => args,
        Err(e) => return flag_error(e),
    };
    if let Err(e) = raypatch::clean_up_on_signals() {
        eprintln!("render-frame: error: {e}");
        return ExitCode::from(2);
    }
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
                Some(mib) => {
                    eprintln!("render-frame: error: --max-buffer-mib {mib}: {}", raypatch::error_line(e.as_ref()))
                }
                None => eprintln!("render-frame: error: {}", raypatch::error_line(e.as_ref())),
            }
            ExitCode::from(raypatch::exit_code(e.as_ref()))
        }
    }
}

/// A flag clap refused (or --help, --version): clap's own message, with a long value it quotes left out.
fn flag_error(e: clap::Error) -> ExitCode {
    let text = e.render().to_string();
    if !e.use_stderr() || text.chars().count() <= MAX_MESSAGE_CHARS {
        e.exit()
    }
    eprintln!("{}", raypatch::raypatch_model::error::one_line(text.trim_end()));
    ExitCode::from(2)
}

/// Indices picked by `--FLAG LIST` among `count` items (`all`, or comma-separated indices).
fn pick(flag: &str, list: &str, count: usize, what: &str) -> Result<Vec<usize>> {
    if list.trim() == "all" {
        return Ok((0..count).collect());
    }
    let mut picked = Vec::new();
    for part in list.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let i: usize = part
            .parse()
            .with_context(|| format!("--{flag} {}: {} is not an index or `all`", quote(list), quote(part)))?;
        if i >= count {
            bail!("--{flag} {i}: the scene has {count} {what} (0 to {})", count.saturating_sub(1));
        }
        picked.push(i);
    }
    if picked.is_empty() {
        bail!("--{flag} {}: no {what} selected", quote(list));
    }
    Ok(picked)
}

fn run(args: &Args) -> Result<()> {
    if args.list_adapters {
        for (i, adapter) in Engine::adapters().iter().enumerate() {
            println!("{adapter}{}", if i == 0 { "  [default]" } else { "" });
        }
        return Ok(());
    }
    if let (Some(out), Some(model)) = (&args.save_model, &args.model) {
        let count = raypatch::save_checkpoint_model(model, out)?;
        println!("wrote {}: {count} tensors", out.display());
        return Ok(());
    }
    let adapter = args.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
    let max_buffer_bytes = args.max_buffer_mib.map(|mib| mib << 20);
    let matmul = args.matmul_kernel;
    let context = if matmul.is_some() { "--adapter / --matmul-kernel" } else { "--adapter" };
    let precision = args.precision;
    let engine = Engine::new(EngineOptions { adapter, max_buffer_bytes, matmul, precision, ..Default::default() })
        .context(context)?;
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
    let (shots, path_fps) = cameras::shots(&args.cameras, &data, &views, args.view.is_some(), model.ray_kind())?;
    check_patch_size(&shots, model.target_sizes(), args.cameras.size.is_some())?;
    let outputs = requested_outputs(args, &shots, model.outputs())?;
    let destinations = files::destinations(args, &shots, &data, outputs)?;
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
    let sequence = Sequence {
        shots: &shots,
        request,
        panels: args.panels.as_deref().unwrap_or_default(),
        depth_range: args.depth_range,
        input: &inputs[0].image,
        fps: args.fps.unwrap_or_else(|| path_fps.unwrap_or(DEFAULT_FPS).clamp(1.0, 100.0)),
        mp4: args.mp4.unwrap_or_default(),
        progress: !args.quiet,
        keep: args.metrics || args.out_raw.is_some(),
        batched: is_sequence(&args.cameras),
    };
    let rendering = sequence.render(&scene, &destinations)?;
    let rendered = &rendering.kept;
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
        report::metrics(&truths, rendered, shots[0].camera.width())?
    } else {
        Vec::new()
    };
    let mut repeats = Vec::with_capacity(args.repeat);
    for _ in 0..args.repeat {
        let start = Instant::now();
        scene.render(&shots[0].camera, &request)?;
        repeats.push(start.elapsed());
    }
    rendering.writing.commit()?;

    let k = model.patch_size();
    let region = rendering.region;
    let region_text =
        args.region.map_or(String::new(), |r| format!(" (region x={} y={} {}x{})", r.x, r.y, r.width, r.height));
    let family = model.config().name();
    println!(
        "rendered {} view(s) of {}x{}{region_text} ({}) from {} input view(s) with {} ({family}, k={k}, {:.2}M parameters) on {}",
        rendering.frames,
        shots[0].camera.width(),
        shots[0].camera.height(),
        outputs.iter().map(Output::name).collect::<Vec<_>>().join(", "),
        inputs.len(),
        model.path(),
        model.parameter_count() as f64 / 1e6,
        engine.adapter()
    );
    let fps = rendering.frames as f64 / rendering.total.as_secs_f64();
    println!(
        "encode {:.1} ms, render {:.1} ms ({} image(s) of {}x{}, {fps:.2} per second, {} per render call); wrote {}",
        ms(encode_time),
        ms(rendering.total),
        rendering.frames,
        region.width,
        region.height,
        rendering.batch,
        written(&destinations.files)
    );
    for line in &metric_lines {
        println!("{line}");
    }
    if args.timings {
        println!("{}", model.computes_as());
        println!(
            "load {:.1} ms, encode {:.1} ms, first render {:.1} ms (with its plan: buffers allocated, pipelines \
             compiled)",
            ms(load_time),
            ms(encode_time),
            ms(rendering.first),
        );
        if rendering.each.len() > 1 {
            println!("later renders: {}", summary(&rendering.each[1..]));
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
        if let Some(note) = raypatch::driver_cache_note() {
            println!("{note}");
        }
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
    let panels = args.panels.as_deref().unwrap_or_default();
    let panel_output = |o: Output| panels.iter().any(|p| p.output() == Some(o));
    for panel in panels {
        outputs = outputs.with(panel.output().unwrap_or(Output::Rgb));
    }
    if args.depth_range.is_some() && args.depth.is_none() && !panel_output(Output::Depth) {
        bail!("--depth-range: only with --depth or --panels with depth");
    }
    let flag = |o: Output| match o {
        Output::Segmentation if args.segmentation.is_some() => "--segmentation".to_string(),
        Output::Depth if args.depth.is_some() => "--depth".to_string(),
        o if panel_output(o) => format!("--panels {}", o.name()),
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
                 `depth_file_path`) for a depth model; not --orbit, --orbit-frames, --pose, --camera-path, --motion or --interpolate"
            );
        }
    }
    for output in outputs.iter() {
        let (written, writers) = match output {
            Output::Rgb => (true, ""),
            Output::Segmentation => (
                args.segmentation.is_some() || args.out_raw.is_some() || args.metrics || panel_output(output),
                "--segmentation DIR|FILE.png or --out-raw FILE",
            ),
            Output::Depth => (
                args.depth.is_some() || args.out_raw.is_some() || (args.metrics && depth_truth) || panel_output(output),
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

/// Whether the shots are a sequence of frames (batched, with a progress bar) rather than views or one camera.
fn is_sequence(cameras: &CameraArgs) -> bool {
    cameras.motion.is_some() || cameras.interpolate || cameras.camera_path.is_some() || cameras.orbit_frames.is_some()
}

/// The files a run wrote, for its summary line: every one, or the first and last of many.
fn written(files: &raypatch::OutputFiles) -> String {
    let paths: Vec<String> = files.paths().map(|p| p.display().to_string()).collect();
    match &paths[..] {
        [first, .., last] if paths.len() > 4 => format!("{first} ... {last} ({} files)", paths.len()),
        _ => paths.join(", "),
    }
}

#[cfg(test)]
mod tests {
    use raypatch::raypatch_engine::EngineError;

    /// The exit status of each kind of error, found under render-frame's own context.
    #[test]
    fn exit_statuses_follow_the_error_kind() {
        let status =
            |e: raypatch::Error| raypatch::exit_code(anyhow::Error::from(e).context("--model m.safetensors").as_ref());
        assert_eq!(status(raypatch::Error::Input("target size 50x30".into())), 2);
        assert_eq!(status(raypatch::Error::Cameras { path: "pose.json".into(), reason: "no".into() }), 2);
        assert_eq!(status(raypatch::Error::Engine(EngineError::Device("lost".into()))), 3);
        assert_eq!(status(raypatch::Error::Engine(EngineError::Bug("plan".into()))), 70);
        assert_eq!(raypatch::exit_code(anyhow::anyhow!("--frames 0: expected at least one frame").as_ref()), 2);
    }

    /// The line render-frame prints: the context, then each cause an outer message does not already quote.
    #[test]
    fn an_error_is_one_line_of_its_causes() {
        let inner = anyhow::Error::from(raypatch::Error::Input("pose: number 3 is NaN\nexpected finite".into()));
        let e = inner.context("--pose camera.json").context("--pose camera.json: cannot read");
        assert_eq!(
            raypatch::error_line(e.as_ref()),
            "--pose camera.json: cannot read: pose: number 3 is NaN expected finite"
        );
    }
}
