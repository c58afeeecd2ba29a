//! The bundled trained models on the bundled test scenes: each model's mean PSNR and SSIM over the target views of
//! the scenes its docs/QUALITY.md row names equal the figures that row gives (PSNR within 1 dB, SSIM within 0.02),
//! so the models, the scenes and the document cannot drift apart (a retrained model must come with its new figures).
//!
//! Rows of QUALITY.md's bundled-scenes table: `| `assets/models/NAME.safetensors` | k | PSNR | SSIM | on |`. The
//! last cell names the scene a model is measured on when it is a backticked `assets/scenes/…` path (the model fitted
//! to the default scene is measured on that scene only); otherwise the row is measured on all bundled scenes.

use std::path::{Path, PathBuf};

use raypatch::metrics::{psnr, ssim};
use raypatch::{Engine, EngineOptions, Request, SceneData};

const TOLERANCE_DB: f64 = 1.0;
const TOLERANCE_SSIM: f64 = 0.02;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

struct Row {
    model: PathBuf,
    k: usize,
    psnr: f64,
    ssim: f64,
    /// None: all bundled scenes.
    scene: Option<PathBuf>,
}

/// The rows of QUALITY.md's bundled-scenes table.
fn documented() -> Vec<Row> {
    let text = std::fs::read_to_string(root().join("docs/QUALITY.md")).expect("docs/QUALITY.md");
    text.lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.trim().trim_matches('|').split('|').map(str::trim).collect();
            let path = cells.first()?.strip_prefix('`')?.strip_suffix('`')?;
            if !path.starts_with("assets/models/") || cells.len() < 4 {
                return None;
            }
            let k = cells[1].parse().unwrap_or_else(|_| panic!("QUALITY.md: bad k in {line:?}"));
            let psnr = cells[2].parse().unwrap_or_else(|_| panic!("QUALITY.md: bad PSNR in {line:?}"));
            let ssim = cells[3].parse().unwrap_or_else(|_| panic!("QUALITY.md: bad SSIM in {line:?}"));
            let scene = cells
                .get(4)
                .and_then(|cell| cell.split('`').nth(1))
                .filter(|p| p.starts_with("assets/scenes/"))
                .map(|p| root().join(p));
            Some(Row { model: root().join(path), k, psnr, ssim, scene })
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
fn bundled_models_reach_the_psnr_and_ssim_quality_md_gives_on_the_bundled_scenes() {
    let documented = documented();
    let models = bundled("assets/models");
    assert!(models.len() >= 4, "assets/models should hold SRT and RP-SRT k = 2, 4, 8: {models:?}");
    for model in &models {
        assert!(documented.iter().any(|row| &row.model == model), "docs/QUALITY.md gives no PSNR for {model:?}");
    }
    let scene_paths = bundled("assets/scenes");
    let scenes: Vec<SceneData> = scene_paths.iter().map(|p| SceneData::load(p).unwrap()).collect();
    assert!(!scenes.is_empty(), "assets/scenes holds no scene");

    let engine = Engine::new(EngineOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)");
    for row in documented {
        let path = &row.model;
        let model = engine.load(path).unwrap();
        assert_eq!(model.patch_size(), row.k, "{path:?}: k in docs/QUALITY.md");
        let chosen: Vec<&SceneData> = match &row.scene {
            None => scenes.iter().collect(),
            Some(scene) => {
                let index = scene_paths
                    .iter()
                    .position(|p| p == scene)
                    .unwrap_or_else(|| panic!("{path:?}: docs/QUALITY.md names {scene:?}, not a bundled scene"));
                vec![&scenes[index]]
            }
        };
        let (mut psnrs, mut ssims) = (Vec::new(), Vec::new());
        for data in chosen {
            let scene = model.encode(&data.inputs).unwrap();
            for target in &data.targets {
                let rgb = scene.render(&target.camera, &Request::default()).unwrap().rgb().unwrap();
                let truth = target.image.as_ref().expect("bundled scenes have target images");
                psnrs.push(psnr(&rgb, truth).unwrap());
                ssims.push(ssim(&rgb, truth).unwrap());
            }
        }
        let got_psnr = psnrs.iter().sum::<f64>() / psnrs.len() as f64;
        let got_ssim = ssims.iter().sum::<f64>() / ssims.len() as f64;
        let on = row.scene.as_ref().map_or("all bundled scenes".to_string(), |p| format!("{p:?}"));
        println!(
            "{path:?} on {on}: {got_psnr:.3} dB, SSIM {got_ssim:.4} on {} target views; docs/QUALITY.md {:.2} dB, {:.3}",
            psnrs.len(),
            row.psnr,
            row.ssim
        );
        assert!(
            (got_psnr - row.psnr).abs() <= TOLERANCE_DB,
            "{path:?} on {on}: PSNR {got_psnr:.3} dB, docs/QUALITY.md says {:.2} dB",
            row.psnr
        );
        assert!(
            (got_ssim - row.ssim).abs() <= TOLERANCE_SSIM,
            "{path:?} on {on}: SSIM {got_ssim:.4}, docs/QUALITY.md says {:.3}",
            row.ssim
        );
    }
}
