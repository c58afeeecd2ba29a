//! The bundled trained models on the bundled test scenes: each model's mean PSNR over the scenes' target views
//! equals the figure docs/QUALITY.md gives for it within 1 dB, so the models, the scenes and the document
//! cannot drift apart (a retrained model must come with its new figures).

use std::path::{Path, PathBuf};

use raypatch::metrics::psnr;
use raypatch::{Engine, EngineOptions, Request, SceneData};

const TOLERANCE_DB: f64 = 1.0;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The rows of QUALITY.md's bundled-scenes table: `| `assets/models/NAME.safetensors` | k | PSNR |`.
fn documented_psnr() -> Vec<(PathBuf, usize, f64)> {
    let text = std::fs::read_to_string(root().join("docs/QUALITY.md")).expect("docs/QUALITY.md");
    text.lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.trim().trim_matches('|').split('|').map(str::trim).collect();
            let path = cells.first()?.strip_prefix('`')?.strip_suffix('`')?;
            if !path.starts_with("assets/models/") || cells.len() < 3 {
                return None;
            }
            let k = cells[1].parse().unwrap_or_else(|_| panic!("QUALITY.md: bad k in {line:?}"));
            let psnr = cells[2].parse().unwrap_or_else(|_| panic!("QUALITY.md: bad PSNR in {line:?}"));
            Some((root().join(path), k, psnr))
        })
        .collect()
}

fn bundled(folder: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(root().join(folder))
        .unwrap_or_else(|e| panic!("{folder}: {e}"))
        .map(|entry| entry.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "safetensors"))
        .collect();
    files.sort();
    files
}

#[test]
fn bundled_models_reach_the_psnr_quality_md_gives_on_the_bundled_scenes() {
    let documented = documented_psnr();
    let models = bundled("assets/models");
    assert!(models.len() >= 4, "assets/models should hold SRT and RP-SRT k = 2, 4, 8: {models:?}");
    for model in &models {
        assert!(documented.iter().any(|(p, _, _)| p == model), "docs/QUALITY.md gives no PSNR for {model:?}");
    }
    let scenes: Vec<SceneData> = bundled("assets/scenes").iter().map(|p| SceneData::load(p).unwrap()).collect();
    assert!(!scenes.is_empty(), "assets/scenes holds no scene");

    let engine = Engine::new(EngineOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)");
    for (path, k, want) in documented {
        let model = engine.load(&path).unwrap();
        assert_eq!(model.patch_size(), k, "{path:?}: k in docs/QUALITY.md");
        let mut values = Vec::new();
        for data in &scenes {
            let scene = model.encode(&data.inputs).unwrap();
            for target in &data.targets {
                let rgb = scene.render(&target.camera, &Request::default()).unwrap().rgb.unwrap();
                values.push(psnr(&rgb, target.image.as_ref().expect("bundled scenes have target images")).unwrap());
            }
        }
        let got = values.iter().sum::<f64>() / values.len() as f64;
        println!("{path:?}: {got:.3} dB on {} target views, docs/QUALITY.md {want:.2} dB", values.len());
        assert!((got - want).abs() <= TOLERANCE_DB, "{path:?}: PSNR {got:.3} dB, docs/QUALITY.md says {want:.2} dB");
    }
}
