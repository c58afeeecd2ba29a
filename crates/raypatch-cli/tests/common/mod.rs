//! Helpers shared by the render-frame subprocess tests.
#![allow(dead_code)] // each test file uses its own subset

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DMat4;
use raypatch::{Camera, Image};
use safetensors::tensor::TensorView;
use safetensors::Dtype;

pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).ancestors().nth(2).unwrap().to_path_buf()
}

pub fn golden(case: &str, file: &str) -> String {
    root().join("assets/golden").join(case).join(file).display().to_string()
}

pub struct Run {
    pub code: i32,
    pub stdout: String,
    pub stderr: String,
}

/// Runs render-frame in `dir` with `args`.
pub fn run(dir: &Path, args: &[&str]) -> Run {
    let out = Command::new(env!("CARGO_BIN_EXE_render-frame")).args(args).current_dir(dir).output().unwrap();
    Run {
        code: out.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// Every file under `dir`, relative.
pub fn files(dir: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.strip_prefix(dir).unwrap().display().to_string();
        if path.is_dir() {
            found.extend(files(&path).into_iter().map(|f| format!("{name}/{f}")));
        }
        found.push(name);
    }
    found.sort();
    found
}

/// Runs a bad input in `dir` and checks: exit code 2, one stderr line containing each of `expected`, and no
/// file created in `dir`.
pub fn fails(dir: &Path, args: &[&str], expected: &[&str]) {
    let before = files(dir);
    let r = run(dir, args);
    assert_eq!(r.code, 2, "{args:?}: exit code {} (stderr: {})", r.code, r.stderr);
    let lines: Vec<&str> = r.stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert!(lines.len() == 1 || lines[0].starts_with("error:"), "{args:?}: not one line: {:?}", r.stderr);
    for text in expected {
        assert!(r.stderr.contains(text), "{args:?}: {:?} does not mention {text:?}", r.stderr);
    }
    assert!(!r.stderr.contains("panicked"), "{args:?}: panicked: {}", r.stderr);
    assert_eq!(files(dir), before, "{args:?}: files were left behind");
}

pub fn png_size(path: &Path) -> (usize, usize) {
    let image = Image::load_png(path).unwrap();
    (image.width(), image.height())
}

/// The tensors of a safetensors file as (name, dtype, shape, bytes), in name order.
pub type Tensors = BTreeMap<String, (Dtype, Vec<usize>, Vec<u8>)>;

pub fn read_f32_tensors(path: &str) -> (Tensors, HashMap<String, String>) {
    let bytes = std::fs::read(path).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let tensors =
        file.tensors().into_iter().map(|(k, t)| (k, (t.dtype(), t.shape().to_vec(), t.data().to_vec()))).collect();
    (tensors, header.metadata().clone().unwrap_or_default())
}

pub fn write_tensors(path: &Path, tensors: &Tensors, metadata: &HashMap<String, String>) {
    let views: Vec<(String, TensorView)> = tensors
        .iter()
        .map(|(name, (dtype, shape, bytes))| (name.clone(), TensorView::new(*dtype, shape.clone(), bytes).unwrap()))
        .collect();
    std::fs::write(path, safetensors::serialize(views, Some(metadata.clone())).unwrap()).unwrap();
}

/// A copy of a scene or model file with `edit` applied to its tensors, written into `dir`.
pub fn edited(dir: &Path, source: &str, name: &str, edit: impl FnOnce(&mut Tensors)) -> String {
    let (mut tensors, metadata) = read_f32_tensors(source);
    edit(&mut tensors);
    let path = dir.join(name);
    write_tensors(&path, &tensors, &metadata);
    path.display().to_string()
}

/// A copy of a model file with `edit` applied to the config in its metadata, written into `dir`.
pub fn with_config(dir: &Path, source: &str, name: &str, edit: impl FnOnce(&mut serde_json::Value)) -> String {
    let (tensors, mut metadata) = read_f32_tensors(source);
    let mut config: serde_json::Value = serde_json::from_str(&metadata["config"]).unwrap();
    edit(&mut config);
    metadata.insert("config".into(), config.to_string());
    let path = dir.join(name);
    write_tensors(&path, &tensors, &metadata);
    path.display().to_string()
}

pub fn set_f32(tensors: &mut Tensors, key: &str, index: usize, value: f32) {
    tensors.get_mut(key).unwrap().2[4 * index..4 * index + 4].copy_from_slice(&value.to_le_bytes());
}

/// A safetensors file whose header is `header` (JSON) followed by `data`.
pub fn raw_file(dir: &Path, name: &str, header: &str, data: &[u8]) -> String {
    let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend_from_slice(data);
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path.display().to_string()
}

/// A folder of `count` frames (32x24 PNGs) with MSN cameras written as NeRF poses in transforms.json.
pub fn frames_folder(dir: &Path, count: usize) -> PathBuf {
    let folder = dir.join("frames");
    std::fs::create_dir_all(&folder).unwrap();
    let mut frames = Vec::new();
    for i in 0..count {
        let angle = (40.0 + 70.0 * i as f64).to_radians();
        let position = glam::DVec3::new(7.0 * angle.cos(), 7.0 * angle.sin(), 2.5);
        let (_, cv) = Camera::msn(position, 32, 24).unwrap().as_pinhole().unwrap();
        let gl = DMat4::from_cols(cv.x_axis, -cv.y_axis, -cv.z_axis, cv.w_axis);
        let rows: Vec<Vec<f64>> = (0..4).map(|r| gl.row(r).to_array().to_vec()).collect();
        frames.push(serde_json::json!({ "file_path": format!("./r_{i}"), "transform_matrix": rows }));
        let pixels = (0..32 * 24 * 3).map(|v| ((v * (i + 3)) % 256) as f32 / 255.0).collect();
        Image::new(32, 24, pixels).unwrap().save_png(folder.join(format!("r_{i}.png"))).unwrap();
    }
    let transforms = serde_json::json!({ "camera_angle_x": 2.0 * (0.016f64 / 0.035).atan(), "frames": frames });
    std::fs::write(folder.join("transforms.json"), serde_json::to_string_pretty(&transforms).unwrap()).unwrap();
    folder
}
