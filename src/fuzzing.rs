//! Entry points for the fuzz targets (`fuzz/`, `cargo fuzz`) and their corpus regression test
//! (`tests/fuzz_corpus.rs`): each parser of untrusted bytes, called as `render-frame` calls it. Each returns
//! whether the input was accepted; none may panic, hang or allocate beyond what the input declares and the
//! documented limits allow.

use crate::{Camera, Image, SceneData};

/// A safetensors file: layout checks, header, tensors.
pub fn safetensors_file(data: &[u8]) -> bool {
    raypatch_model::TensorFile::parse("fuzz.safetensors", data).is_ok()
}

/// A model file: the layout, then the config in its metadata, its counts against the file, and every
/// tensor's name, shape and dtype as the model's module tree fetches them (no GPU).
pub fn model_file(data: &[u8]) -> bool {
    raypatch_model::TensorFile::parse("fuzz.safetensors", data)
        .and_then(raypatch_model::weights::model_from_file)
        .is_ok_and(|loaded| raypatch_engine::models::build(&loaded, raypatch_engine::nn::ReadLimits::NONE).is_ok())
}

/// A Lightning checkpoint: the zip archive, its pickle, the tensors and config made into a model file, then
/// the model checked as [`model_file`] checks it.
pub fn checkpoint_file(data: &[u8]) -> bool {
    raypatch_model::weights::model_from_bytes("fuzz.ckpt", data)
        .is_ok_and(|loaded| raypatch_engine::models::build(&loaded, raypatch_engine::nn::ReadLimits::NONE).is_ok())
}

/// A checkpoint's pickle (`archive/data.pkl`) alone, where mutations are not stopped by the zip's CRCs: the
/// interpreter, then the state_dict's tensor views and the config.
pub fn checkpoint_pickle(data: &[u8]) -> bool {
    use raypatch_model::checkpoint::{pickle, state_dict, torch};
    pickle::interpret(data).is_ok_and(|p| state_dict(&p).is_ok() && torch::model_config(&p).is_ok())
}

/// A scene file: the layout, the scene tensors, and the cameras built from them.
pub fn scene_file(data: &[u8]) -> bool {
    SceneData::from_bytes("fuzz.safetensors", data).is_ok()
}

/// A frame folder: the bytes up to the first NUL are `transforms.json`, the rest is the PNG every frame
/// names (written into a fresh folder, then read as `render-frame --scene FOLDER` reads it), and the JSON is
/// also read as a `--pose` file.
pub fn frames_folder(data: &[u8]) -> bool {
    let split = data.iter().position(|&b| b == 0).unwrap_or(data.len());
    let (json, png) = (&data[..split], data.get(split + 1..).unwrap_or_default());
    let _ = Image::decode_png("fuzz.png", png);
    let dir = std::env::temp_dir().join(format!("raypatch-fuzz-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    if std::fs::create_dir_all(&dir).is_err() {
        return false;
    }
    let written =
        std::fs::write(dir.join("transforms.json"), json).and_then(|()| std::fs::write(dir.join("a.png"), png));
    let accepted = written.is_ok() && SceneData::from_frames(&dir).is_ok();
    if let Ok(like) = Camera::msn(glam::DVec3::new(5.0, 1.0, 2.0), 8, 6) {
        let _ = crate::load_pose(dir.join("transforms.json"), &like);
    }
    let _ = std::fs::remove_dir_all(&dir);
    accepted
}
