//! Loading a model or scene file that is wrong in one way gives an error naming the file, the tensor and
//! what was expected. The good files are the bundled golden case `srt_k1`. A model's tensors are checked as
//! its module tree fetches them (`raypatch_engine::models::build`, no GPU).

use std::collections::HashMap;

use raypatch_engine::{models, EngineError};
use raypatch_model::{
    load_model, views::scene_from_file, weights::model_from_file, InputViews, ModelError, TensorFile,
};
use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};

fn golden(file: &str) -> Vec<u8> {
    let path = format!("{}/../../assets/golden/srt_k1/{file}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// (name, dtype, shape, bytes) of every tensor, plus the metadata.
type Tensors = Vec<(String, Dtype, Vec<usize>, Vec<u8>)>;

fn unpack(bytes: &[u8]) -> (Tensors, HashMap<String, String>) {
    let (_, header) = SafeTensors::read_metadata(bytes).unwrap();
    let st = SafeTensors::deserialize(bytes).unwrap();
    let tensors =
        st.tensors().into_iter().map(|(n, v)| (n, v.dtype(), v.shape().to_vec(), v.data().to_vec())).collect();
    (tensors, header.metadata().clone().unwrap_or_default())
}

fn pack(tensors: &Tensors, metadata: &HashMap<String, String>) -> Vec<u8> {
    let views: Vec<(String, TensorView)> =
        tensors.iter().map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap())).collect();
    safetensors::serialize(views, Some(metadata.clone())).unwrap()
}

/// Applies `edit` to the golden model and returns the loading error.
fn model_error(edit: impl FnOnce(&mut Tensors, &mut HashMap<String, String>)) -> String {
    let (mut tensors, mut metadata) = unpack(&golden("model.safetensors"));
    edit(&mut tensors, &mut metadata);
    let file = TensorFile::parse("edited.safetensors", &pack(&tensors, &metadata)).unwrap();
    let built = model_from_file(file)
        .map_err(EngineError::from)
        .and_then(|loaded| models::build(&loaded, raypatch_engine::nn::ReadLimits::NONE).map(drop));
    built.unwrap_err().to_string()
}

fn scene_error(edit: impl FnOnce(&mut Tensors, &mut HashMap<String, String>)) -> String {
    let (mut tensors, mut metadata) = unpack(&golden("scene.safetensors"));
    edit(&mut tensors, &mut metadata);
    let file = TensorFile::parse("scene.safetensors", &pack(&tensors, &metadata)).unwrap();
    scene_from_file(&file).unwrap_err().to_string()
}

fn assert_mentions(err: &str, parts: &[&str]) {
    for p in parts {
        assert!(err.contains(p), "error {err:?} does not mention {p:?}");
    }
}

#[test]
fn golden_model_loads() {
    let path = format!("{}/../../assets/golden/srt_k1/model.safetensors", env!("CARGO_MANIFEST_DIR"));
    let model = load_model(&path).unwrap();
    models::build(&model, raypatch_engine::nn::ReadLimits::NONE).unwrap();
    assert_eq!(model.config.patch_size(), 1);
    assert!(model.parameter_count() > 0);
}

/// The weights a model reads are checked before each read against one GPU buffer and, in all, against the
/// host's free memory: the tensor that would pass either is named and nothing more is read.
#[test]
fn reads_stop_at_the_limits() {
    use raypatch_engine::nn::ReadLimits;
    let path = format!("{}/../../assets/golden/srt_k1/model.safetensors", env!("CARGO_MANIFEST_DIR"));
    let model = load_model(&path).unwrap();
    let total = ReadLimits { tensor_bytes: u64::MAX, total_bytes: 4096 };
    let err = models::build(&model, total).map(drop).unwrap_err().to_string();
    assert!(
        err.contains("srt_k1/model.safetensors: tensor `") && err.contains("bytes of memory the host has free"),
        "{err}"
    );
    let one = ReadLimits { tensor_bytes: 64, total_bytes: u64::MAX };
    let err = models::build(&model, one).map(drop).unwrap_err().to_string();
    assert!(err.contains("more than the 64 bytes one buffer may have"), "{err}");
}

#[test]
fn missing_tensor_is_named() {
    let key = "decoder_att.out_mlp.8.bias";
    let err = model_error(|t, _| t.retain(|(n, ..)| n != key));
    assert_mentions(&err, &["edited.safetensors", "missing", key, "[3]"]);
}

#[test]
fn unexpected_tensor_is_named() {
    let err = model_error(|t, _| t.push(("decoder_att.extra.weight".into(), Dtype::F32, vec![2], vec![0; 8])));
    assert_mentions(&err, &["unexpected", "decoder_att.extra.weight", "[2]"]);
}

#[test]
fn wrong_shape_is_named() {
    let key = "encoder.per_patch_linear.bias";
    let err = model_error(|t, _| {
        let entry = t.iter_mut().find(|(n, ..)| n == key).unwrap();
        entry.2 = vec![entry.2[0] - 1];
        entry.3.truncate(entry.3.len() - 4);
    });
    assert_mentions(&err, &[key, "has shape", "expected"]);
}

#[test]
fn wrong_dtype_is_named() {
    let key = "encoder.per_patch_linear.bias";
    let err = model_error(|t, _| {
        let entry = t.iter_mut().find(|(n, ..)| n == key).unwrap();
        entry.1 = Dtype::I32;
    });
    assert_mentions(&err, &[key, "dtype", "I32", "F32"]);
}

#[test]
fn non_finite_weight_is_named() {
    let key = "encoder.per_patch_linear.bias";
    let err = model_error(|t, _| {
        let entry = t.iter_mut().find(|(n, ..)| n == key).unwrap();
        entry.3[..4].copy_from_slice(&f32::NAN.to_le_bytes());
    });
    assert_mentions(&err, &[key, "NaN"]);
}

#[test]
fn missing_config_says_how_to_convert() {
    let err = model_error(|_, m| {
        m.remove("config");
    });
    assert_mentions(&err, &["config", "convert_checkpoint.py"]);
}

#[test]
fn truncated_file_is_a_format_error() {
    let bytes = golden("model.safetensors");
    for cut in [4, 20, bytes.len() / 2, bytes.len() - 1] {
        let err = TensorFile::parse("cut.safetensors", &bytes[..cut]).unwrap_err();
        assert!(matches!(err, ModelError::Format { .. }), "cut at {cut}: {err}");
        assert_mentions(&err.to_string(), &["cut.safetensors"]);
    }
}

#[test]
fn scene_errors_are_named() {
    let err = scene_error(|t, _| t.retain(|(n, ..)| n != "target_rays"));
    assert_mentions(&err, &["scene.safetensors", "target_rays"]);

    let err = scene_error(|t, _| {
        let e = t.iter_mut().find(|(n, ..)| n == "input_rays").unwrap();
        e.3[..4].copy_from_slice(&f32::INFINITY.to_le_bytes());
    });
    assert_mentions(&err, &["input_rays", "NaN or infinity"]);

    let err = scene_error(|t, _| {
        let e = t.iter_mut().find(|(n, ..)| n == "input_images").unwrap();
        e.3[..4].copy_from_slice(&255.0f32.to_le_bytes());
    });
    assert_mentions(&err, &["input_images", "[0, 1]"]);

    let err = scene_error(|t, _| {
        let e = t.iter_mut().find(|(n, ..)| n == "input_camera_pos").unwrap();
        e.2 = vec![3, 1];
    });
    assert_mentions(&err, &["input_camera_pos", "expected"]);
}

/// The input check takes inputs of any size, as PyTorch does (60x80, height x width, gives 8x10 tokens a view;
/// the golden cases `*_in60x80` and `*_in40x60` render such inputs), and refuses only empty views and buffers
/// that do not hold `count` views of `height`x`width`.
#[test]
fn input_views_of_any_size_pass_the_input_check() {
    let views = |count: usize, height: usize, width: usize| InputViews {
        count,
        height,
        width,
        images: vec![0.5; count * height * width * 3],
        camera_pos: vec![1.0; count * 3],
        rays: vec![0.0; count * height * width * 3],
    };
    for (count, height, width) in [(1, 60, 80), (2, 40, 60), (1, 7, 9), (1, 1, 1)] {
        views(count, height, width).check("inputs").unwrap();
    }
    let err = views(1, 0, 80).check("inputs").unwrap_err().to_string();
    assert_mentions(&err, &["inputs", "input_images", "non-empty"]);
    let mut short = views(2, 60, 80);
    short.rays.truncate(60 * 80 * 3);
    let err = short.check("inputs").unwrap_err().to_string();
    assert_mentions(&err, &["input_rays", "14400 values", "28800"]);
}
