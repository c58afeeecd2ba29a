//! Quality and render time of models on a folder of test scenes, rendered by the engine, plus an optional
//! side-by-side sheet (input | target | one column per model).
//!
//! ```sh
//! cargo run --release --example evaluate -- --scenes DIR --model NAME=MODEL [--model NAME=MODEL ...] \
//!     [--limit N] [--json OUT.json] [--sheet OUT.png --sheet-scenes 4 --sheet-scale 3]
//! ```
//!
//! For every scene file `scene-*.safetensors` in DIR (sorted by name): encodes its input views once per model,
//! renders each target view and compares it with the scene's `target_images`. Prints per model the mean PSNR
//! and SSIM over all target views (the definitions of `render-frame --metrics`: torchmetrics 1.x) and the
//! median encode and render times (wall clock, after the first scene built the plans). docs/QUALITY.md uses it.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use raypatch::metrics::{psnr, ssim};
use raypatch::{Engine, EngineOptions, Error, Image, Request, SceneData};

struct Args {
    scenes: PathBuf,
    models: Vec<(String, PathBuf)>,
    limit: Option<usize>,
    json: Option<PathBuf>,
    sheet: Option<PathBuf>,
    sheet_scenes: usize,
    sheet_scale: usize,
}

/// One model's results.
struct Evaluation {
    name: String,
    path: PathBuf,
    k: usize,
    psnr: Vec<f64>,
    ssim: Vec<f64>,
    encode_ms: Vec<f64>,
    render_ms: Vec<f64>,
    /// Target view 0 of the first `sheet_scenes` scenes.
    sheet_images: Vec<Image>,
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(args) => args,
        Err(message) => {
            eprintln!("evaluate: {message}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("evaluate: error: {e}");
            ExitCode::from(2)
        }
    }
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        scenes: PathBuf::new(),
        models: vec![],
        limit: None,
        json: None,
        sheet: None,
        sheet_scenes: 4,
        sheet_scale: 3,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--scenes" => args.scenes = value()?.into(),
            "--model" => {
                let v = value()?;
                let (name, path) = v.rsplit_once('=').ok_or_else(|| format!("--model {v}: expected NAME=PATH"))?;
                args.models.push((name.to_string(), path.into()));
            }
            "--limit" => args.limit = Some(value()?.parse().map_err(|e| format!("--limit: {e}"))?),
            "--json" => args.json = Some(value()?.into()),
            "--sheet" => args.sheet = Some(value()?.into()),
            "--sheet-scenes" => args.sheet_scenes = value()?.parse().map_err(|e| format!("--sheet-scenes: {e}"))?,
            "--sheet-scale" => args.sheet_scale = value()?.parse().map_err(|e| format!("--sheet-scale: {e}"))?,
            _ => return Err(format!("unknown argument {flag} (see the header of examples/evaluate.rs)")),
        }
    }
    if args.scenes.as_os_str().is_empty() || args.models.is_empty() {
        return Err("--scenes DIR and at least one --model NAME=PATH are required".into());
    }
    Ok(args)
}

fn io_error(path: &Path, action: &'static str) -> impl FnOnce(std::io::Error) -> Error {
    let path = path.display().to_string();
    move |source| Error::Io { path, action, source }
}

fn scene_files(dir: &Path, limit: Option<usize>) -> raypatch::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_error(dir, "cannot list the scene folder"))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.starts_with("scene-") && name.ends_with(".safetensors")
        })
        .collect();
    files.sort();
    files.truncate(limit.unwrap_or(usize::MAX));
    if files.is_empty() {
        return Err(Error::Io {
            path: dir.display().to_string(),
            action: "holds no scene-*.safetensors file",
            source: std::io::ErrorKind::NotFound.into(),
        });
    }
    Ok(files)
}

fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN)
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

fn evaluate(
    engine: &Engine,
    name: &str,
    path: &Path,
    scenes: &[SceneData],
    files: &[PathBuf],
    sheet_scenes: usize,
) -> raypatch::Result<Evaluation> {
    let model = engine.load(path)?;
    let mut e = Evaluation {
        name: name.to_string(),
        path: path.to_path_buf(),
        k: model.patch_size(),
        psnr: vec![],
        ssim: vec![],
        encode_ms: vec![],
        render_ms: vec![],
        sheet_images: vec![],
    };
    for (i, (data, file)) in scenes.iter().zip(files).enumerate() {
        let start = Instant::now();
        let scene = model.encode(&data.inputs)?;
        e.encode_ms.push(start.elapsed().as_secs_f64() * 1e3);
        for (t, target) in data.targets.iter().enumerate() {
            let start = Instant::now();
            let rgb = scene.render(&target.camera, &Request::default())?.rgb().expect("rgb was requested");
            e.render_ms.push(start.elapsed().as_secs_f64() * 1e3);
            let truth = target.image.as_ref().ok_or_else(|| {
                Error::Views(format!("{}: target view {t} has no target image to compare with", file.display()))
            })?;
            e.psnr.push(psnr(&rgb, truth)?);
            e.ssim.push(ssim(&rgb, truth)?);
            if t == 0 && i < sheet_scenes {
                e.sheet_images.push(rgb);
            }
        }
    }
    // The first scene built the plans and compiled the pipelines: leave it out of the times.
    if scenes.len() > 1 {
        e.encode_ms.remove(0);
        e.render_ms.drain(..scenes[0].targets.len());
    }
    Ok(e)
}

/// Rows of images side by side with a white gap, all of the first image's size, each pixel shown as a
/// `scale`×`scale` block.
fn sheet(rows: &[Vec<&Image>], scale: usize) -> raypatch::Result<Image> {
    let (w, h) = (rows[0][0].width() * scale, rows[0][0].height() * scale);
    let gap = 2 * scale;
    let columns = rows[0].len();
    let (width, height) = (columns * (w + gap) - gap, rows.len() * (h + gap) - gap);
    let mut data = vec![1.0f32; width * height * 3];
    for (r, row) in rows.iter().enumerate() {
        for (c, image) in row.iter().enumerate() {
            for y in 0..h {
                for x in 0..w {
                    let dst = ((r * (h + gap) + y) * width + c * (w + gap) + x) * 3;
                    data[dst..dst + 3].copy_from_slice(&image.pixel(x / scale, y / scale));
                }
            }
        }
    }
    Image::new(width, height, data)
}

fn run(args: &Args) -> raypatch::Result<()> {
    let files = scene_files(&args.scenes, args.limit)?;
    let scenes = files.iter().map(SceneData::load).collect::<raypatch::Result<Vec<_>>>()?;
    let engine = Engine::new(EngineOptions::default())?;
    let targets: usize = scenes.iter().map(|s| s.targets.len()).sum();
    println!("{} scenes ({targets} target views) from {} on {}", scenes.len(), args.scenes.display(), engine.adapter());
    println!("| model | k | PSNR (dB) | SSIM | encode ms (median) | render ms per view (median) |");
    println!("|---|---|---|---|---|---|");
    let mut results = Vec::new();
    for (name, path) in &args.models {
        let e =
            evaluate(&engine, name, path, &scenes, &files, if args.sheet.is_some() { args.sheet_scenes } else { 0 })?;
        println!(
            "| {} | {} | {:.2} | {:.3} | {:.1} | {:.1} |",
            e.name,
            e.k,
            mean(&e.psnr),
            mean(&e.ssim),
            median(&e.encode_ms),
            median(&e.render_ms)
        );
        results.push(e);
    }
    if let Some(path) = &args.json {
        let json: Vec<serde_json::Value> = results
            .iter()
            .map(|e| {
                serde_json::json!({
                    "name": e.name, "model": e.path.display().to_string(), "k": e.k,
                    "scenes": args.scenes.display().to_string(), "scene_count": scenes.len(),
                    "psnr": mean(&e.psnr), "ssim": mean(&e.ssim), "ssim_definition": "torchmetrics-1",
                    "psnr_per_view": e.psnr, "encode_ms_median": median(&e.encode_ms),
                    "render_ms_median": median(&e.render_ms), "adapter": engine.adapter(),
                })
            })
            .collect();
        let text = serde_json::to_string_pretty(&json).expect("JSON of numbers and strings") + "\n";
        std::fs::write(path, text).map_err(io_error(path, "cannot write the JSON"))?;
    }
    if let Some(path) = &args.sheet {
        let shown = args.sheet_scenes.min(scenes.len());
        let rows: Vec<Vec<&Image>> = (0..shown)
            .map(|i| {
                let truth = scenes[i].targets[0].image.as_ref().expect("checked while evaluating");
                let mut row = vec![&scenes[i].inputs[0].image, truth];
                row.extend(results.iter().map(|e| &e.sheet_images[i]));
                row
            })
            .collect();
        sheet(&rows, args.sheet_scale.max(1))?.save_png(path)?;
        let names: Vec<&str> = results.iter().map(|e| e.name.as_str()).collect();
        println!("wrote {} (columns: input | target | {})", path.display(), names.join(" | "));
    }
    Ok(())
}
