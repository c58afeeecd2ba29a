//! `render-frame --serve`'s flags and its run: load, encode each scene once per model, start the HTTP side,
//! render on the caller's thread and one more until Ctrl-C (or SIGTERM, SIGHUP), which raypatch's signal
//! clean-up turns into a stop of the render queue (the connections finish, the pipeline cache is saved) and an
//! exit code of 128 + the signal's number.

use std::net::{IpAddr, SocketAddr, TcpListener};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Parser;
use raypatch::{AdapterChoice, Engine, EngineOptions, Model, Outputs, Precision, Request, Scene, SceneData};
use serde_json::json;

use crate::catalog::{info_json, ModelEntry, SceneEntry, MAX_PIXELS, MAX_SIDE};
use crate::conn::Limits;
use crate::http::HttpError;
use crate::queue::{Frame, Job, Reply};
use crate::server::{Http, Shared, CLIENT_FRAMES_PER_SECOND};

/// Threads taking renders from the queue, the caller's among them. Two keep the GPU busy: while one waits for
/// its render and reads it back, the other's render is submitted (the engine runs renders of one plan at once,
/// each with its own staging), so the GPU does not idle between frames.
const RENDER_THREADS: usize = 2;

/// Render plans kept per encoded scene (one per size and output asked for); past this they are dropped, so
/// that requests for ever new sizes cannot grow GPU memory.
const MAX_CACHED_PLANS: usize = 8;

/// The flags of `render-frame --serve`.
#[derive(Parser, Debug)]
#[command(
    name = "render-frame --serve",
    version,
    about = "Serve a live viewer of raypatch renders in the browser: drag to orbit, scroll to zoom, keys to move",
    after_help = "The page and `GET /render.png?pose=...&size=WxH&model=M&scene=S&output=rgb` are described in the README \
                  (\"Live viewer\"). Ctrl-C stops the server."
)]
struct ServeArgs {
    /// Serve the viewer (this set of flags).
    #[arg(long)]
    serve: bool,
    /// Port to listen on (0: any free port; the URL printed says which).
    #[arg(long, default_value_t = 8765)]
    port: u16,
    /// Address to listen on. Anything but loopback lets other machines render on this one.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1")]
    host: IpAddr,
    /// A model file; repeat for several (the page picks by index) [default: the bundled model].
    #[arg(long = "model", value_name = "FILE")]
    models: Vec<PathBuf>,
    /// A scene file or NeRF folder; repeat for several [default: the bundled scene].
    #[arg(long = "scene", value_name = "PATH")]
    scenes: Vec<PathBuf>,
    /// Adapter to use: the first whose name contains this text (default: a real GPU, else lavapipe).
    #[arg(long)]
    adapter: Option<String>,
    /// `f32` (default), `f16` (f16 linear weights) or `f16-act` (the tensor path: cooperative matrices where the
    /// device has them), as render-frame's --precision; the page shows which kernels ran.
    #[arg(long, value_name = "P", default_value = "f32", value_parser = PossibleValuesParser::new(Precision::ALL.map(Precision::name))
        .map(|name: String| Precision::from_name(&name).unwrap_or_default()))]
    precision: Precision,
}

/// Whether the command line asks for the viewer (`--serve` anywhere among the arguments).
pub fn requested() -> bool {
    std::env::args_os().skip(1).any(|a| a == "--serve")
}

/// A file built into the program: the name it stands for in messages, and its bytes.
pub type Bundled = (&'static str, &'static [u8]);

/// `render-frame --serve`: parses the flags, serves until Ctrl-C (exit code 130; 143 for SIGTERM); on an error,
/// one line and the exit code of its kind (`raypatch::exit_code`, as render-frame's).
pub fn main(default_model: Bundled, default_scene: Bundled) -> ExitCode {
    // Before any thread or wgpu instance (a no-op where render-frame's main did it already): Mesa's shader cache
    // where it can be written, or off (issue 50).
    raypatch::prepare_driver_cache();
    let args = ServeArgs::parse();
    match run(&args, default_model, default_scene) {
        Ok(signal) => ExitCode::from(u8::try_from(128 + signal).unwrap_or(1)),
        Err(e) => {
            eprintln!("render-frame: error: {}", raypatch::error_line(e.as_ref()));
            ExitCode::from(raypatch::exit_code(e.as_ref()))
        }
    }
}

/// Serves until a signal stops it; the signal's number.
fn run(args: &ServeArgs, default_model: Bundled, default_scene: Bundled) -> Result<i32> {
    let adapter = args.adapter.clone().map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
    let options = EngineOptions { adapter, precision: args.precision, ..Default::default() };
    let engine = Engine::new(options).context("--adapter")?;
    let models: Vec<Model> = if args.models.is_empty() {
        vec![engine.load_bytes(default_model.0, default_model.1)?]
    } else {
        args.models
            .iter()
            .map(|p| engine.load(p).with_context(|| format!("--model {}", p.display())))
            .collect::<Result<_>>()?
    };
    let scene_data: Vec<(String, SceneData)> = if args.scenes.is_empty() {
        vec![(default_scene.0.to_string(), SceneData::from_bytes(default_scene.0, default_scene.1)?)]
    } else {
        let load = |p: &PathBuf| SceneData::load(p).with_context(|| format!("--scene {}", p.display()));
        args.scenes.iter().map(|p| Ok((p.display().to_string(), load(p)?))).collect::<Result<_>>()?
    };
    let address = SocketAddr::new(args.host, args.port);
    let listener = TcpListener::bind(address).with_context(|| format!("--host {} --port {}", args.host, args.port))?;
    let start = Instant::now();
    let scenes = encode_all(&models, &scene_data)?;
    let model_entries: Vec<ModelEntry> = models.iter().map(ModelEntry::of).collect();
    let scene_entries =
        scene_data.iter().map(|(name, data)| SceneEntry::of(name, data)).collect::<raypatch::Result<Vec<_>>>()?;
    let details = engine.adapter_details();
    let adapter = format!("{} ({})", details.name, details.backend);
    let connections = Limits::new();
    let limits = json!({
        "max_side": MAX_SIDE,
        "max_pixels": MAX_PIXELS,
        "client_frames_per_second": CLIENT_FRAMES_PER_SECOND,
        "max_connections": connections.connections,
    });
    let info = info_json(&model_entries, &scene_entries, &adapter, limits);
    let shared = Arc::new(Shared::new(model_entries, scene_entries, info));
    let url = format!("http://{}/", listener.local_addr()?);
    let http = Http::start(listener, shared.clone(), connections).context("cannot start the server threads")?;
    let (stopper, stopped) = (shared.clone(), Arc::new(AtomicI32::new(0)));
    let stopped_by = stopped.clone();
    raypatch::clean_up_on_signals_then(move |signal| {
        stopped_by.store(signal, Ordering::Release);
        stopper.queue.stop();
    })
    .context("cannot catch Ctrl-C")?;
    println!(
        "raypatch viewer: {url} ({} model(s) x {} scene(s) encoded in {:.1} s on {adapter}; Ctrl-C stops)",
        models.len(),
        scene_data.len(),
        start.elapsed().as_secs_f64()
    );
    std::thread::scope(|scope| {
        for i in 1..RENDER_THREADS {
            let thread = std::thread::Builder::new().name(format!("viewer-render-{i}"));
            // Without it the caller's thread renders alone, as well but with the GPU idle between frames.
            let _ = thread.spawn_scoped(scope, || render_jobs(&shared, &scenes));
        }
        render_jobs(&shared, &scenes);
    });
    http.stop(Duration::from_secs(2));
    println!("raypatch viewer: stopped");
    Ok(stopped.load(Ordering::Acquire))
}

/// Every scene encoded by every model, `[model][scene]`.
fn encode_all<'m>(models: &'m [Model], scenes: &[(String, SceneData)]) -> Result<Vec<Vec<Scene<'m>>>> {
    models
        .iter()
        .map(|model| {
            scenes
                .iter()
                .map(|(name, data)| {
                    let context = || format!("--scene {name} with --model {}", model.path());
                    data.check_rays(model.ray_kind()).with_context(context)?;
                    model.encode(&data.inputs).with_context(context)
                })
                .collect()
        })
        .collect()
}

/// Renders the queue's jobs until it stops.
fn render_jobs(shared: &Shared, scenes: &[Vec<Scene>]) {
    while let Some(job) = shared.queue.next() {
        let reply = catch_unwind(AssertUnwindSafe(|| render(&job, scenes, &shared.scenes)))
            .unwrap_or_else(|_| Err(HttpError::new(500, "render: the engine failed on this request")));
        // The client may have gone; its worker then no longer waits.
        let _ = job.reply.send(reply);
    }
}

/// One render: the camera the job asks for, through its model's encoding of its scene.
fn render(job: &Job, scenes: &[Vec<Scene>], entries: &[SceneEntry]) -> Reply {
    let query = &job.query;
    let camera = entries[query.scene].camera(query.pose, query.width, query.height).map_err(|e| HttpError::of(&e))?;
    let scene = &scenes[query.model][query.scene];
    if scene.cached_plans() >= MAX_CACHED_PLANS {
        scene.engine_scene().clear_render_plans();
    }
    let request = Request { outputs: Outputs::of(&[query.output.output()]), region: None };
    let start = Instant::now();
    let rendered = scene.render(&camera, &request).map_err(|e| HttpError::of(&e).about("render"))?;
    Ok(Frame { rendered, render_time: start.elapsed() })
}
