//! render-frame's depth outputs as a subprocess: depth pictures and depth metrics against a scene's
//! `target_depth`, depth PNGs in frame folders, and the one-line errors of depth flags and depth tensors that
//! are wrong. The other good runs and bad inputs are in `tests/cli.rs`.

mod common;

use std::path::Path;

use common::*;
use raypatch::raypatch_model::TensorFile;
use raypatch::Image;
use safetensors::Dtype;
use tempfile::TempDir;

fn raw_f32(path: &Path, key: &str) -> Vec<f32> {
    TensorFile::open(path).unwrap().f32(key).unwrap().data
}

/// `scene` with a `target_depth` tensor of `shape` and `values`, written into `dir`.
fn with_depth(dir: &Path, scene: &str, name: &str, shape: Vec<usize>, values: &[f32]) -> String {
    edited(dir, scene, name, |t| {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        t.insert("target_depth".into(), (Dtype::F32, shape, bytes));
    })
}

#[test]
fn depth_pictures_and_depth_metrics() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (model, scene) = (golden("srt_k1_depth", "model.safetensors"), golden("srt_k1_depth", "scene.safetensors"));
    let base = ["--model", model.as_str(), "--scene", scene.as_str()];
    let r = run(d, &[&base[..], &["--depth", "depth.png", "--out-raw", "raw.safetensors"]].concat());
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("(rgb, depth)") && r.stdout.contains("depth.png"), "{}", r.stdout);
    // The picture: the depth of the raw output in turbo colours over its own range, centred above the legend.
    let depth = raw_f32(&d.join("raw.safetensors"), "depth");
    assert_eq!(depth.len(), 24 * 16);
    let range = depth.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let picture = Image::load_png(d.join("depth.png")).unwrap();
    assert!(picture.width() >= 24 && picture.height() > 16 + 7, "{}x{}", picture.width(), picture.height());
    let x0 = (picture.width() - 24) / 2;
    for (x, y) in [(0, 0), (23, 0), (5, 9), (23, 15)] {
        let want = Image::depth_colour(depth[y * 24 + x], range).map(|c| (c * 255.0).round() / 255.0);
        let got = picture.pixel(x0 + x, y);
        assert!(want.iter().zip(got).all(|(a, b)| (a - b).abs() < 1e-6), "({x}, {y}): {got:?} != {want:?}");
    }
    // The legend is black text on white below a colour bar.
    let legend: Vec<[f32; 3]> = (0..picture.width()).map(|x| picture.pixel(x, picture.height() - 4)).collect();
    assert!(legend.contains(&[0.0; 3]) && legend.contains(&[1.0; 3]), "no text in the legend's last rows");

    // A fixed range: depth outside it takes the end colours; a folder per view.
    let r = run(d, &[&base[..], &["--outputs", "depth", "--depth", "pics", "--depth-range", "0.5,4"]].concat());
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(files(&d.join("pics")), vec!["view_000.png"]);
    assert!(r.stdout.contains("wrote pics/view_000.png") && !r.stdout.contains("render.png"), "{}", r.stdout);
    let fixed = Image::load_png(d.join("pics/view_000.png")).unwrap();
    let x0 = (fixed.width() - 24) / 2;
    let want = Image::depth_colour(depth[0], (0.5, 4.0)).map(|c| (c * 255.0).round() / 255.0);
    assert!(want.iter().zip(fixed.pixel(x0, 0)).all(|(a, b)| (a - b).abs() < 1e-6));

    // Metrics against the scene's target_depth (metres; 0 = none), as metrics::depth_errors computes them.
    let truth: Vec<f32> = (0..24 * 16).map(|i| if i % 7 == 0 { 0.0 } else { 0.5 + (i % 24) as f32 * 0.1 }).collect();
    let depth_scene = with_depth(d, &scene, "depth-scene.safetensors", vec![1, 16, 24], &truth);
    let r = run(d, &["--model", &model, "--scene", &depth_scene, "--metrics", "--out", "m.png"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let e = raypatch::metrics::depth_errors(&depth, &truth).unwrap();
    let view = format!(
        "target view 0: Abs.Rel {:.4}, Sq.Rel {:.4}, RMSE {:.4} m over {} pixels with depth",
        e.abs_rel, e.sq_rel, e.rmse, e.pixels
    );
    assert!(r.stdout.contains(&view), "no {view:?} in {}", r.stdout);
    assert!(r.stdout.contains("mean over 1 view(s): depth of all views as the official test"), "{}", r.stdout);
    assert!(e.pixels == 24 * 16 - 55 && e.abs_rel.is_finite());
}

#[test]
fn depth_flags_and_files_that_are_wrong() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (model, scene) = (golden("srt_k1_depth", "model.safetensors"), golden("srt_k1_depth", "scene.safetensors"));
    let base = ["--model", model.as_str(), "--scene", scene.as_str()];
    let (rgb_model, rgb_scene) = (golden("rpsrt_k4", "model.safetensors"), golden("rpsrt_k4", "scene.safetensors"));
    fails(
        d,
        &["--model", &rgb_model, "--scene", &rgb_scene, "--depth", "d.png"],
        &["--depth", "depth was requested but this model has no depth channel"],
    );
    fails(d, &["--depth", "d.png"], &["--depth", "no depth channel"]);
    fails(
        d,
        &[&base[..], &["--depth", "d.png", "--depth-range", "3,1"]].concat(),
        &["--depth-range", "0 <= MIN < MAX"],
    );
    fails(d, &[&base[..], &["--depth", "d.png", "--depth-range", "1"]].concat(), &["--depth-range", "MIN,MAX"]);
    fails(d, &[&base[..], &["--depth-range", "1,3"]].concat(), &["--depth"]);
    fails(d, &[&base[..], &["--depth", "d.txt"]].concat(), &["--depth", "d.txt", ".png"]);
    fails(d, &[&base[..], &["--outputs", "depth"]].concat(), &["--outputs depth", "--depth DIR|FILE.png"]);
    fails(
        d,
        &[&base[..], &["--depth", "render.png"]].concat(),
        &["--depth", "render.png", "the same file as an output of --out"],
    );
    // target_depth must have the target size.
    let f = with_depth(d, &scene, "bad-depth.safetensors", vec![1, 24, 16], &[1.0; 24 * 16]);
    fails(
        d,
        &["--model", &model, "--scene", &f, "--metrics"],
        &["bad-depth.safetensors", "`target_depth`", "expected [1,16,24]"],
    );
    std::fs::remove_file(&f).unwrap();
}

#[test]
fn frame_folders_carry_depth_pngs_in_millimetres() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let folder = frames_folder(d, 3);
    let transforms = folder.join("transforms.json");
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&transforms).unwrap()).unwrap();
    for i in 0..3 {
        // 16-bit millimetres; 0 (no depth) in the first column.
        let mm: Vec<u16> = (0..32 * 24).map(|p| if p % 32 == 0 { 0 } else { 1500 + 10 * (p % 32) as u16 }).collect();
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(32, 24, mm)
            .unwrap()
            .save(folder.join(format!("d_{i}.png")))
            .unwrap();
        json["frames"][i]["depth_file_path"] = serde_json::json!(format!("d_{i}.png"));
    }
    std::fs::write(&transforms, json.to_string()).unwrap();
    let data = raypatch::SceneData::load(&folder).unwrap();
    let depth = data.targets[2].depth.as_ref().expect("the frame's depth");
    assert_eq!((depth[0], depth[1], depth[31 + 32]), (0.0, 1.51, 1.81));
    assert!(data.files.iter().any(|f| f.ends_with("d_2.png")), "{:?}", data.files);

    let model = golden("srt_k1_depth", "model.safetensors");
    let scene = folder.display().to_string();
    let r = run(d, &["--model", &model, "--scene", &scene, "--metrics", "--depth", "depth.png"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(
        r.stdout.contains("target view 2: PSNR") && r.stdout.contains(&format!("over {} pixels with depth", 31 * 24))
    );
    assert!(d.join("depth.png").exists() && d.join("render.png").exists());
    // An output may not overwrite a depth map it read.
    fails(
        d,
        &["--model", &model, "--scene", &scene, "--depth", &folder.join("d_2.png").display().to_string()],
        &["would overwrite the input"],
    );

    // A depth map of another size, and one in colour.
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(16, 24, vec![1000u16; 16 * 24])
        .unwrap()
        .save(folder.join("d_1.png"))
        .unwrap();
    fails(d, &["--scene", &scene], &["d_1.png", "depth map is 16x24, its frame's image is 32x24"]);
    Image::new(32, 24, vec![0.5; 32 * 24 * 3]).unwrap().save_png(folder.join("d_1.png")).unwrap();
    fails(d, &["--scene", &scene], &["d_1.png", "grey PNG"]);
    json["frames"][1]["depth_file_path"] = serde_json::json!(7);
    std::fs::write(&transforms, json.to_string()).unwrap();
    fails(d, &["--scene", &scene], &["transforms.json", "frame 1: `depth_file_path` is 7"]);
}
