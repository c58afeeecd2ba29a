//! Renders a turntable of a scene: the first target camera turned about the world z axis, one PNG per frame.
//!
//! ```sh
//! cargo run --release --example turntable -- [MODEL SCENE OUT_DIR FRAMES]
//! ```
//!
//! Defaults: the bundled RP-SRT k=4 model fitted to the bundled scene, that scene, `turntable/`, 12 frames.

use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use raypatch::{Engine, EngineOptions, Request, SceneData};

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("turntable: error: {e}");
            ExitCode::from(2)
        }
    }
}

fn run() -> raypatch::Result<()> {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    let mut args = std::env::args().skip(1);
    let model_path = args.next().map_or(assets.join("models/fitted_scene-2000000_rpsrt_k4.safetensors"), Into::into);
    let scene_path = args.next().map_or(assets.join("scenes/scene-2000000.safetensors"), Into::into);
    let out_dir = args.next().map_or("turntable".into(), std::path::PathBuf::from);
    let frames: usize = args.next().and_then(|n| n.parse().ok()).unwrap_or(12);

    let engine = Engine::new(EngineOptions::default())?;
    let model = engine.load(&model_path)?;
    let data = SceneData::load(&scene_path)?;
    let start = Instant::now();
    let scene = model.encode(&data.inputs)?;
    println!(
        "encoded {} input view(s) in {:.1} ms on {}",
        data.inputs.len(),
        start.elapsed().as_secs_f64() * 1e3,
        engine.adapter()
    );

    std::fs::create_dir_all(&out_dir).map_err(|e| raypatch::Error::Io {
        path: out_dir.display().to_string(),
        action: "cannot create the folder",
        source: e,
    })?;
    let first = &data.targets[0].camera;
    let start = Instant::now();
    for i in 0..frames {
        // Every frame has the same size, so all but the first reuse the first frame's plan and buffers.
        let camera = first.orbited(360.0 * i as f64 / frames as f64);
        let rgb = scene.render(&camera, &Request::default())?.rgb().expect("rgb is rendered by default");
        rgb.save_png(out_dir.join(format!("frame_{i:03}.png")))?;
    }
    println!(
        "rendered {frames} frames of {}x{} into {} in {:.1} ms",
        first.width(),
        first.height(),
        out_dir.display(),
        start.elapsed().as_secs_f64() * 1e3
    );
    Ok(())
}
