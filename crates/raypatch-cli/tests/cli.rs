//! render-frame as a subprocess: good runs write what they say; every bad input exits with code 2, one line
//! on stderr naming the file, tensor or flag and what was expected, and leaves no output file behind. The depth
//! outputs' tests are in `tests/depth.rs`.

mod common;

use std::path::Path;

use common::*;
use glam::DMat4;
use raypatch::raypatch_model::TensorFile;
use raypatch::{Camera, Image};
use safetensors::Dtype;
use tempfile::TempDir;

#[test]
fn no_arguments_renders_the_bundled_scene_into_render_png() {
    let dir = TempDir::new().unwrap();
    let r = run(dir.path(), &[]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(png_size(&dir.path().join("render.png")), (80, 60));
    assert!(r.stdout.contains("rendered 1 view(s) of 80x60") && r.stdout.contains("k=4"), "{}", r.stdout);
    assert!(r.stdout.contains("encode") && r.stdout.contains(" ms"), "{}", r.stdout);
    assert_eq!(files(dir.path()), vec!["render.png"]);
}

/// `--precision f16` renders the same view within f16's rounding (tests/stress/f16.rs bounds it); an unknown
/// precision is a one-line error naming the flag.
#[test]
fn precision_f16_renders_close_to_f32() {
    let dir = TempDir::new().unwrap();
    let render = |precision: &str| {
        let out = dir.path().join(format!("{precision}.safetensors"));
        let r = run(dir.path(), &["--precision", precision, "--out-raw", out.to_str().unwrap()]);
        if r.code == 2 && r.stderr.contains("need shader-f16") {
            return None;
        }
        assert_eq!(r.code, 0, "{}", r.stderr);
        Some(TensorFile::open(&out).unwrap().f32("rgb").unwrap().data)
    };
    let f32_rgb = render("f32").expect("f32 needs no feature");
    match render("f16") {
        Some(rgb) => {
            let diff = rgb.iter().zip(&f32_rgb).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(diff > 0.0 && diff < 1e-2, "--precision f16 moved rgb by {diff}");
        }
        None => eprintln!("the adapter has no shader-f16: --precision f16 not tested"),
    }
    fails(dir.path(), &["--precision", "f8"], &["--precision", "f16-act"]);
}

#[test]
fn target_views_match_pytorch_with_metrics_and_raw_output() {
    let dir = TempDir::new().unwrap();
    let (model, scene) = (golden("rpsrt_k2", "model.safetensors"), golden("rpsrt_k2", "scene.safetensors"));
    let args =
        ["--model", &model, "--scene", &scene, "--view", "all", "--out", "views", "--out-raw", "raw.safetensors"];
    let r = run(dir.path(), &[&args[..], &["--metrics", "--timings"]].concat());
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(png_size(&dir.path().join("views/view_000.png")), (24, 16));
    assert_eq!(png_size(&dir.path().join("views/view_001.png")), (24, 16));
    for text in [
        "target view 0: PSNR",
        "target view 1: PSNR",
        "mean over 2 view(s): PSNR",
        "SSIM",
        "planned peak GPU memory",
        "pipelines: ",
        "precision f32, ",
    ] {
        assert!(r.stdout.contains(text), "no {text:?} in {}", r.stdout);
    }
    // The raw output is the model's: equal to PyTorch's within the golden tolerance.
    let raw = TensorFile::open(&dir.path().join("raw.safetensors")).unwrap().f32("rgb").unwrap();
    let want = TensorFile::open(Path::new(&golden("rpsrt_k2", "expected.safetensors"))).unwrap().f32("rgb").unwrap();
    assert_eq!(raw.shape, want.shape);
    let err = raw.data.iter().zip(&want.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(err <= 1e-4, "CLI rgb differs from PyTorch by {err}");

    // A region writes just that region, equal to the same pixels of the full render.
    let r = run(
        dir.path(),
        &[
            "--model",
            &model,
            "--scene",
            &scene,
            "--view",
            "1",
            "--region",
            "3,5,9,7",
            "--out",
            "part.png",
            "--out-raw",
            "part.safetensors",
        ],
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(png_size(&dir.path().join("part.png")), (9, 7));
    let part = TensorFile::open(&dir.path().join("part.safetensors")).unwrap().f32("rgb").unwrap();
    assert_eq!(part.shape, vec![1, 7, 9, 3]);
    for y in 0..7 {
        for x in 0..27 {
            let full = raw.data[((16 + 5 + y) * 24 + 3) * 3 + x];
            assert!((part.data[y * 27 + x] - full).abs() <= 1e-6, "region pixel ({x}/3, {y}) differs");
        }
    }
}

#[test]
fn osrt_segmentation_masks_depth_and_fg_ari() {
    let dir = TempDir::new().unwrap();
    let (model, scene) = (golden("rposrt_k8", "model.safetensors"), golden("rposrt_k8", "scene.safetensors"));
    let expected = TensorFile::open(Path::new(&golden("rposrt_k8", "expected.safetensors"))).unwrap();
    let args = ["--model", &model, "--scene", &scene, "--view", "all", "--segmentation", "masks", "--metrics"];
    let r = run(dir.path(), &[&args[..], &["--out", "rgb", "--out-raw", "raw.safetensors"]].concat());
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("RP-OSRT, k=8") && r.stdout.contains("(rgb, segmentation)"), "{}", r.stdout);
    for view in ["view_000.png", "view_001.png"] {
        assert_eq!(png_size(&dir.path().join("masks").join(view)), (48, 32));
        assert_eq!(png_size(&dir.path().join("rgb").join(view)), (48, 32));
    }
    // The raw segmentation is the model's (PyTorch's within the golden tolerance); the pooled FG-ARI is the
    // official figure.
    let raw = TensorFile::open(&dir.path().join("raw.safetensors")).unwrap().f32("segmentation").unwrap();
    let want = expected.f32("segmentation").unwrap();
    assert_eq!(raw.shape, want.shape);
    let err = raw.data.iter().zip(&want.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(err <= 1e-4, "CLI segmentation differs from PyTorch by {err}");
    let official = expected.f64_values("fg_ari").unwrap()[0];
    let line = r.stdout.lines().find(|l| l.starts_with("mean over 2 view(s)")).expect("a mean line");
    assert!(line.contains(&format!("as the official test: {official:.4}")), "{line} (official {official})");
    assert!(r.stdout.contains("target view 1: PSNR") && r.stdout.contains("FG-ARI"), "{}", r.stdout);

    // Segmentation alone: no rgb PNG is written.
    let r = run(
        dir.path(),
        &["--model", &model, "--scene", &scene, "--outputs", "segmentation", "--segmentation", "m.png"],
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(dir.path().join("m.png").exists() && !dir.path().join("render.png").exists());

    // depth = exp(logdepth) of a depth model.
    let (model, scene) = (golden("srt_k1_depth", "model.safetensors"), golden("srt_k1_depth", "scene.safetensors"));
    let r = run(
        dir.path(),
        &["--model", &model, "--scene", &scene, "--outputs", "rgb,logdepth,depth", "--out-raw", "d.safetensors"],
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    let raw = TensorFile::open(&dir.path().join("d.safetensors")).unwrap();
    let (log, depth) = (raw.f32("logdepth").unwrap(), raw.f32("depth").unwrap());
    assert_eq!(depth.shape, vec![1, 16, 24]);
    for (l, d) in log.data.iter().zip(&depth.data) {
        assert!((l.exp() - d).abs() <= 1e-6 * d.abs().max(1.0), "exp({l}) = {} != {d}", l.exp());
    }
}

#[test]
fn novel_views_turntables_poses_and_depth() {
    let dir = TempDir::new().unwrap();
    let r = run(dir.path(), &["--orbit", "-30", "--out", "orbit.png"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(png_size(&dir.path().join("orbit.png")), (80, 60));

    let r = run(dir.path(), &["--orbit-frames", "3", "--out", "turntable"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    for i in 0..3 {
        assert_eq!(png_size(&dir.path().join(format!("turntable/frame_{i:03}.png"))), (80, 60));
    }
    assert!(r.stdout.contains("rendered 3 view(s)"), "{}", r.stdout);

    // A pose file: a NeRF-axes camera-to-world matrix, intrinsics and size of its own.
    let (_, cv) = Camera::msn(glam::DVec3::new(-4.0, 6.0, 3.0), 16, 8).unwrap().as_pinhole().unwrap();
    let gl = DMat4::from_cols(cv.x_axis, -cv.y_axis, -cv.z_axis, cv.w_axis);
    let rows: Vec<Vec<f64>> = (0..4).map(|r| gl.row(r).to_array().to_vec()).collect();
    let pose = serde_json::json!({ "camera_angle_x": 0.9, "w": 16, "h": 8, "transform_matrix": rows });
    std::fs::write(dir.path().join("pose.json"), pose.to_string()).unwrap();
    let r = run(dir.path(), &["--pose", "pose.json", "--out", "posed.png"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(png_size(&dir.path().join("posed.png")), (16, 8));

    let (model, scene) = (golden("srt_k1_depth", "model.safetensors"), golden("srt_k1_depth", "scene.safetensors"));
    let r = run(
        dir.path(),
        &["--model", &model, "--scene", &scene, "--logdepth", "--out", "depth.png", "--out-raw", "depth.safetensors"],
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    let raw = TensorFile::open(&dir.path().join("depth.safetensors")).unwrap();
    assert_eq!(raw.shape("logdepth"), Some(&[1usize, 16, 24][..]));

    let r = run(dir.path(), &["--list-adapters"]);
    assert_eq!(r.code, 0);
    assert!(!r.stdout.trim().is_empty());
}

#[test]
fn png_folders_with_transforms_json() {
    let dir = TempDir::new().unwrap();
    let folder = frames_folder(dir.path(), 3);
    let scene = folder.display().to_string();
    // Default: the last frame is the target, the others are the inputs.
    let r = run(dir.path(), &["--scene", &scene, "--metrics"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("from 2 input view(s)") && r.stdout.contains("target view 2: PSNR"), "{}", r.stdout);
    assert_eq!(png_size(&dir.path().join("render.png")), (32, 24));
    let r = run(dir.path(), &["--scene", &scene, "--input-views", "1", "--view", "0,2", "--out", "out"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(dir.path().join("out/view_000.png").exists() && dir.path().join("out/view_002.png").exists());
}

#[test]
fn bad_flags_and_paths() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    fails(d, &["--model", "missing.safetensors"], &["missing.safetensors", "cannot read"]);
    fails(d, &["--model", "."], &["cannot read"]);
    fails(d, &["--scene", "nowhere"], &["nowhere", "cannot read"]);
    fails(d, &["--region", "1,2,3"], &["--region", "X,Y,W,H"]);
    fails(d, &["--region", "76,0,9,4"], &["region", "not inside the 80x60"]);
    fails(d, &["--view", "9"], &["--view 9", "2 target views"]);
    fails(d, &["--input-views", ""], &["--input-views", "no input views selected"]);
    fails(d, &["--input-views", "0,x"], &["--input-views", "\"x\""]);
    fails(d, &["--adapter", "no-such-gpu"], &["no adapter whose name contains \"no-such-gpu\""]);
    let (golden_model, golden_scene) =
        (golden("rpsrt_k4", "model.safetensors"), golden("rpsrt_k4", "scene.safetensors"));
    fails(d, &["--model", &golden_model, "--scene", &golden_scene, "--metrics"], &["--metrics", "ground-truth"]);
    fails(d, &["--max-buffer-mib", "0"], &["--max-buffer-mib", "0"]);
    fails(d, &["--orbit-frames", "0"], &["--orbit-frames 0"]);
    fails(d, &["--orbit-frames", "2", "--orbit", "NaN"], &["--orbit NaN", "finite angle"]);
    fails(d, &["--logdepth", "--out-raw", "x.safetensors"], &["log-depth", "no depth channel"]);
    fails(d, &["--segmentation", "m.png"], &["--segmentation", "no object slots"]);
    fails(d, &["--outputs", "rgb,shape"], &["--outputs", "unknown output \"shape\"", "segmentation"]);
    let (osrt_model, osrt_scene) = (golden("osrt", "model.safetensors"), golden("osrt", "scene.safetensors"));
    let osrt = ["--model", osrt_model.as_str(), "--scene", osrt_scene.as_str()];
    fails(d, &[&osrt[..], &["--outputs", "segmentation"]].concat(), &["--outputs segmentation", "--segmentation"]);
    fails(
        d,
        &[&osrt[..], &["--outputs", "depth", "--out-raw", "x.safetensors"]].concat(),
        &["depth", "no depth channel"],
    );
    fails(d, &[&osrt[..], &["--segmentation", "m.txt"]].concat(), &["--segmentation", "m.txt", ".png"]);
    std::fs::write(d.join("plain-file"), b"").unwrap();
    fails(d, &["--out", "plain-file/render.png"], &["--out", "plain-file", "does not exist"]);
    fails(d, &["--out-raw", "no/such/dir/raw.safetensors"], &["--out-raw", "no/such/dir", "does not exist"]);
    fails(d, &["--out", "plain-file/sub"], &["--out", "cannot create the folder"]);
}

#[test]
fn malformed_safetensors_files() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let model = golden("rpsrt_k4", "model.safetensors");
    let bytes = std::fs::read(&model).unwrap();
    std::fs::write(d.join("truncated.safetensors"), &bytes[..bytes.len() - 100]).unwrap();
    fails(
        d,
        &["--model", "truncated.safetensors"],
        &["truncated.safetensors", "not a valid safetensors file", "truncated file?"],
    );
    std::fs::write(d.join("short.safetensors"), &bytes[..5]).unwrap();
    fails(d, &["--model", "short.safetensors"], &["short.safetensors", "too short for the 8-byte header length"]);
    let mut huge = bytes.clone();
    huge[..8].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    std::fs::write(d.join("huge-header.safetensors"), huge).unwrap();
    fails(d, &["--model", "huge-header.safetensors"], &["huge-header.safetensors", "header length", "is more than"]);
    let mut past_end = bytes.clone();
    past_end[..8].copy_from_slice(&(bytes.len() as u64).to_le_bytes());
    std::fs::write(d.join("past-end.safetensors"), past_end).unwrap();
    fails(d, &["--model", "past-end.safetensors"], &["past-end.safetensors", "header length", "is more than"]);

    let data = [0u8; 32];
    let outside =
        raw_file(d, "outside.safetensors", r#"{"a":{"dtype":"F32","shape":[8],"data_offsets":[0,64]}}"#, &data);
    fails(
        d,
        &["--scene", &outside],
        &["outside.safetensors", "`a` has data_offsets [0, 64] outside the 32-byte data section"],
    );
    let overlap = raw_file(
        d,
        "overlap.safetensors",
        r#"{"a":{"dtype":"F32","shape":[4],"data_offsets":[0,16]},"b":{"dtype":"F32","shape":[4],"data_offsets":[8,24]}}"#,
        &data,
    );
    fails(d, &["--scene", &overlap], &["overlap.safetensors", "tensors `a` [0, 16] and `b` [8, 24] overlap"]);
    let dtype = raw_file(d, "dtype.safetensors", r#"{"a":{"dtype":"F33","shape":[8],"data_offsets":[0,32]}}"#, &data);
    fails(d, &["--scene", &dtype], &["dtype.safetensors", "tensor `a` has unknown dtype \"F33\""]);
    let misfit = raw_file(d, "misfit.safetensors", r#"{"a":{"dtype":"F32","shape":[4],"data_offsets":[0,32]}}"#, &data);
    fails(d, &["--scene", &misfit], &["misfit.safetensors", "shape [4] of F32 does not fill data_offsets [0, 32]"]);
    let trailing =
        raw_file(d, "trailing.safetensors", r#"{"a":{"dtype":"F32","shape":[4],"data_offsets":[0,16]}}"#, &data);
    fails(d, &["--scene", &trailing], &["trailing.safetensors", "trailing bytes"]);
    let json = raw_file(d, "json.safetensors", r#"{"a":"#, &data);
    fails(d, &["--scene", &json], &["json.safetensors", "invalid JSON"]);
}

#[test]
fn wrong_tensors_in_scenes_and_models() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let scene = golden("rpsrt_k4", "scene.safetensors");
    let model = golden("rpsrt_k4", "model.safetensors");

    let f = edited(d, &scene, "no-rays.safetensors", |t| {
        t.remove("input_rays");
    });
    fails(d, &["--scene", &f], &["no-rays.safetensors", "missing tensor `input_rays`"]);
    let f = edited(d, &model, "extra.safetensors", |t| {
        t.insert("decoder_rp.extra.weight".into(), (Dtype::F32, vec![1], vec![0; 4]));
    });
    fails(d, &["--model", &f], &["extra.safetensors", "unexpected tensor `decoder_rp.extra.weight`"]);
    let f = edited(d, &model, "misshapen.safetensors", |t| {
        let w = t.get_mut("decoder_rp.conv_decoder.conv_0.bias").unwrap();
        w.1 = vec![w.1[0] - 1];
        w.2.truncate(w.2.len() - 4);
    });
    fails(d, &["--model", &f], &["misshapen.safetensors", "`decoder_rp.conv_decoder.conv_0.bias` has shape"]);
    let f = edited(d, &scene, "pos.safetensors", |t| {
        let p = t.get_mut("input_camera_pos").unwrap();
        p.1 = vec![1, 6];
    });
    fails(d, &["--scene", &f], &["pos.safetensors", "input_camera_pos", "expected [2,3]"]);
    let f = edited(d, &scene, "f64.safetensors", |t| {
        let p = t.get_mut("input_camera_pos").unwrap();
        p.0 = Dtype::F64;
        p.1 = vec![1, 3];
    });
    fails(d, &["--scene", &f], &["f64.safetensors", "`input_camera_pos` has dtype F64, expected F32"]);
    for (key, index, value, name) in [
        ("input_images", 5, f32::NAN, "nan-image.safetensors"),
        ("target_rays", 7, f32::INFINITY, "inf-ray.safetensors"),
        ("target_camera_pos", 1, f32::NAN, "nan-pose.safetensors"),
    ] {
        let f = edited(d, &scene, name, |t| set_f32(t, key, index, value));
        fails(d, &["--scene", &f], &[name, key, "NaN or infinity"]);
    }
    let f = edited(d, &scene, "no-inputs.safetensors", |t| {
        for key in ["input_images", "input_rays"] {
            let v = t.get_mut(key).unwrap();
            v.1[0] = 0;
            v.2.clear();
        }
        let p = t.get_mut("input_camera_pos").unwrap();
        p.1[0] = 0;
        p.2.clear();
    });
    fails(d, &["--scene", &f], &["no-inputs.safetensors", "at least one non-empty input view"]);
    let f = edited(d, &scene, "size.safetensors", |t| {
        let r = t.get_mut("target_rays").unwrap();
        r.1 = vec![2, 32, 42, 3];
        r.2.truncate(2 * 32 * 42 * 12);
    });
    fails(d, &["--scene", &f], &["target", "42x32 (width x height)", "not divisible by the model's patch size k=4"]);
}

#[test]
fn bad_cameras_and_frames() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let pose = |name: &str, text: &str| {
        std::fs::write(d.join(name), text).unwrap();
        name.to_string()
    };
    let scaled = pose("scaled.json", r#"{"transform_matrix": [[2,0,0,0],[0,2,0,-6],[0,0,2,1],[0,0,0,1]]}"#);
    fails(d, &["--pose", &scaled], &["scaled.json", "not orthonormal"]);
    let inf = pose("inf.json", r#"{"transform_matrix": [[1,0,0,1e999],[0,1,0,0],[0,0,1,5],[0,0,0,1]]}"#);
    fails(d, &["--pose", &inf], &["inf.json"]);
    let short = pose("short.json", r#"{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5]]}"#);
    fails(d, &["--pose", &short], &["short.json", "4 rows of 4 finite numbers"]);
    let odd =
        pose("odd.json", r#"{"w": 50, "h": 32, "transform_matrix": [[1,0,0,0],[0,0,-1,-6],[0,1,0,1],[0,0,0,1]]}"#);
    fails(d, &["--pose", &odd], &["50", "not divisible by the model's patch size k=4"]);
    fails(d, &["--pose", "absent.json"], &["absent.json", "cannot read"]);

    let folder = frames_folder(d, 3);
    let scene = folder.display().to_string();
    let transforms = std::fs::read_to_string(folder.join("transforms.json")).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&transforms).unwrap();
    json["frames"][1]["transform_matrix"][0][0] = serde_json::json!(1.5);
    std::fs::write(folder.join("transforms.json"), json.to_string()).unwrap();
    fails(d, &["--scene", &scene], &["transforms.json", "frame 1 (./r_1)", "not orthonormal"]);
    std::fs::write(folder.join("transforms.json"), &transforms).unwrap();
    Image::new(16, 24, vec![0.5; 16 * 24 * 3]).unwrap().save_png(folder.join("r_2.png")).unwrap();
    fails(d, &["--scene", &scene], &["transforms.json", "frame 2 (./r_2) is 16x24, frame 0 is 32x24", "same size"]);
    std::fs::remove_file(folder.join("r_2.png")).unwrap();
    fails(d, &["--scene", &scene], &["r_2.png", "no such file in the scene folder"]);
    std::fs::write(folder.join("r_2.png"), b"not a png").unwrap();
    fails(d, &["--scene", &scene], &["r_2.png", "not a readable PNG"]);
    std::fs::write(folder.join("transforms.json"), r#"{"frames": []}"#).unwrap();
    fails(d, &["--scene", &scene], &["transforms.json", "no view"]);
}

/// The f32 tensor `key` of a safetensors file written by a run.
/// A size the model's patch size does not divide and a pose that is not rigid are input errors
/// (`raypatch::ErrorKind::Input`): exit code 2, one line naming the flag or file, nothing written.
#[test]
fn bad_sizes_and_poses_are_input_errors() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let nearest = "not divisible by the model's patch size k=4; nearest valid sizes: 48x28, 48x32, 52x28, 52x32";
    fails(d, &["--orbit", "10", "--size", "50x30"], &["--size: target size 50x30", nearest]);
    let sheared = r#"{"transform_matrix": [[1,0.3,0,0],[0,1,0,-6],[0,0,1,1],[0,0,0,1]]}"#;
    std::fs::write(d.join("sheared.json"), sheared).unwrap();
    fails(d, &["--pose", "sheared.json"], &["sheared.json", "pose rotation is not orthonormal"]);
    std::fs::write(d.join("bottom.json"), r#"{"transform_matrix": [[1,0,0,0],[0,1,0,-6],[0,0,1,1],[1,0,0,1]]}"#)
        .unwrap();
    fails(d, &["--pose", "bottom.json"], &["bottom.json", "pose bottom row"]);
}

#[test]
fn rays_of_another_kind_are_refused_naming_the_tensor() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let scene = golden("rpsrt_k4", "scene.safetensors");
    // Unit-depth points (DeFiNe's rays) where an SRT model takes unit directions.
    let f = edited(d, &scene, "points.safetensors", |t| {
        let (pos, rays) = (&t["input_camera_pos"], &t["input_rays"]);
        let (n, h, w) = (rays.1[0], rays.1[1], rays.1[2]);
        let floats: Vec<f32> = pos.2.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        let mut bytes = Vec::new();
        for i in 0..n {
            let centre = glam::Vec3::from_slice(&floats[3 * i..3 * i + 3]).as_dvec3();
            let camera = Camera::msn(centre, w, h).unwrap();
            let points = camera.rays_of(raypatch::RayKind::UnitDepthPoint);
            bytes.extend(points.rays.iter().flat_map(|p| p.to_array()).flat_map(f32::to_le_bytes));
        }
        t.get_mut("input_rays").unwrap().2 = bytes;
    });
    fails(
        d,
        &["--model", &golden("rpsrt_k4", "model.safetensors"), "--scene", &f],
        &[
            "points.safetensors",
            "`input_rays`",
            "view 0",
            "this model takes unit ray directions",
            "look like unit-depth points",
        ],
    );
}

#[test]
fn timings_name_the_pipeline_cache_in_raypatch_cache_dir() {
    let dir = TempDir::new().unwrap();
    let cache = dir.path().join("cache");
    let timed = |value: &std::ffi::OsStr| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_render-frame"))
            .args(["--timings", "--out", "view.png"])
            .env("RAYPATCH_CACHE_DIR", value)
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        stdout.lines().find(|l| l.starts_with("pipelines: ")).unwrap_or_else(|| panic!("{stdout}")).to_string()
    };
    let first = timed(cache.as_os_str());
    assert!(first.contains(" compiled in ") && first.contains(" ms"), "{first}");
    if first.contains("no pipeline cache: ") {
        eprintln!("no pipeline cache on this adapter: {first}");
        assert!(!cache.exists());
    } else {
        assert!(first.contains(&cache.display().to_string()) && first.ends_with("(new)"), "{first}");
        let files = std::fs::read_dir(&cache).unwrap().map(|e| e.unwrap().path()).collect::<Vec<_>>();
        assert_eq!(files.len(), 1, "{files:?}");
        assert!(std::fs::metadata(&files[0]).unwrap().len() > 0);
        assert!(timed(cache.as_os_str()).ends_with(" KiB read)"));
    }
    assert!(timed("off".as_ref()).ends_with("no pipeline cache: RAYPATCH_CACHE_DIR=off"));
}

/// `--timings` says which precision and kernel family ran: at f16-act, the tensor kernels where the device has
/// cooperative matrices, else the adapter's kernels and why (the host's lavapipe; `.ci/coop.sh`'s has them).
#[test]
fn timings_name_the_precision_and_the_kernel_family() {
    let dir = TempDir::new().unwrap();
    let (model, scene) = (golden("rpsrt_k2", "model.safetensors"), golden("rpsrt_k2", "scene.safetensors"));
    let r = run(
        dir.path(),
        &["--model", &model, "--scene", &scene, "--precision", "f16-act", "--timings", "--out", "v.png"],
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    let line =
        r.stdout.lines().find(|l| l.starts_with("precision f16-act, ")).unwrap_or_else(|| panic!("{}", r.stdout));
    assert!(
        line.contains("coop kernels (cooperative matrices") || line.contains("no tensor kernels on this device ("),
        "{line}"
    );
}
