//! The float64 reference of the whole model (`reference::model`), which the rest of this suite and the
//! benchmark harness measure the engine against, checked on every golden case:
//! - with float64 encoding arguments it is the float64 PyTorch run of the official model (`latent_f64`,
//!   `rgb_f64`, `logdepth_f64`): the same maths in the same precision, so only f64 rounding differs;
//! - with the arguments rounded to f32 (as torch float32 and the engine form them) it is within float32
//!   arithmetic error of the float32 PyTorch run and of the engine.

use std::path::{Path, PathBuf};

use raypatch_engine::reference::model::{Argument, ReferenceModel};
use raypatch_engine::{Output, Outputs};
use safetensors::{Dtype, SafeTensors};

use crate::common::max_abs_diff;
use crate::{engine_model, golden_case};

/// Float64 against float64: both compute every sin/cos argument exactly (an f32·f32 product fits in an
/// f64), so what remains is f64 rounding (~1e-16) amplified through the network; 1e-9 leaves a wide margin
/// (~1e-14 is seen).
const F64_TOL: f64 = 1e-9;
/// The engine (and torch float32) against the reference with f32-rounded arguments: the golden tests'
/// tolerance (f32 arithmetic through ~10 layers; ~5e-6 is seen).
const F32_TOL: f64 = 1e-4;

fn f64_tensor(path: &Path, key: &str) -> Vec<f64> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let file = SafeTensors::deserialize(&bytes).unwrap();
    let view = file.tensor(key).unwrap_or_else(|e| panic!("{}: {key}: {e}", path.display()));
    assert_eq!(view.dtype(), Dtype::F64, "{}: {key} is not F64", path.display());
    view.data().chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().unwrap())).collect()
}

fn f32_tensor(path: &Path, key: &str) -> Vec<f32> {
    raypatch_model::TensorFile::open(path).unwrap().f32(key).unwrap().data
}

/// max |a - b|, infinite if either holds a NaN or infinity.
fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "length mismatch");
    a.iter()
        .zip(b)
        .map(|(x, y)| if x.is_finite() && y.is_finite() { (x - y).abs() } else { f64::INFINITY })
        .fold(0.0, f64::max)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

fn golden_cases() -> Vec<PathBuf> {
    let dir = golden_case("");
    let mut cases: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("expected.safetensors").exists())
        .collect();
    cases.sort();
    assert!(cases.len() >= 5, "expected the golden cases in {}", dir.display());
    cases
}

#[test]
fn reference_model_matches_float64_pytorch() {
    let _memory = crate::sharing_memory();
    for dir in golden_cases() {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let model = raypatch_model::load_model(dir.join("model.safetensors")).unwrap();
        let scene = raypatch_model::load_scene(dir.join("scene.safetensors")).unwrap();
        let expected = dir.join("expected.safetensors");
        let reference = ReferenceModel::new(&model, Argument::Float64).unwrap();
        let encoded = reference.encode(&scene.inputs).unwrap();
        let frame = reference.render(&encoded, &scene.targets).unwrap();

        let latent = f64_tensor(&expected, "latent_f64");
        let latent_err = max_diff(&encoded.latent, &latent) / max_abs(&latent);
        let rgb_err = max_diff(&frame.rgb, &f64_tensor(&expected, "rgb_f64"));
        eprintln!("{name}: float64 reference vs float64 PyTorch: latent rel {latent_err:.1e}, rgb {rgb_err:.1e}");
        assert!(latent_err <= F64_TOL, "{name}: latent relative error {latent_err:e} > {F64_TOL:e}");
        assert!(rgb_err <= F64_TOL, "{name}: rgb error {rgb_err:e} > {F64_TOL:e}");
        if let Some(depth) = &frame.logdepth {
            let want = f64_tensor(&expected, "logdepth_f64");
            let err = max_diff(depth, &want) / max_abs(&want);
            assert!(err <= F64_TOL, "{name}: log-depth relative error {err:e} > {F64_TOL:e}");
        }
    }
}

#[test]
fn engine_and_float32_pytorch_match_the_reference_with_f32_arguments() {
    let _memory = crate::sharing_memory();
    for dir in golden_cases() {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let loaded = raypatch_model::load_model(dir.join("model.safetensors")).unwrap();
        let scene = raypatch_model::load_scene(dir.join("scene.safetensors")).unwrap();
        let reference = ReferenceModel::new(&loaded, Argument::RoundedToF32).unwrap();
        let want = reference.render(&reference.encode(&scene.inputs).unwrap(), &scene.targets).unwrap();

        let model = engine_model(&loaded);
        let frame = model.encode(&scene.inputs).unwrap().render(&scene.targets, Outputs::default()).unwrap();
        let engine_err = max_abs_diff(frame.get(Output::Rgb).expect("rgb"), &want.rgb);
        let torch_err = max_abs_diff(&f32_tensor(&dir.join("expected.safetensors"), "rgb"), &want.rgb);
        let f32_vs_f64 = max_diff(&want.rgb, &f64_tensor(&dir.join("expected.safetensors"), "rgb_f64"));
        eprintln!(
            "{name}: rgb vs the reference with f32 arguments: engine {engine_err:.1e}, torch f32 {torch_err:.1e}; \
             f32 arguments vs f64 arguments {f32_vs_f64:.1e}"
        );
        assert!(engine_err <= F32_TOL, "{name}: engine rgb error {engine_err:e} > {F32_TOL:e}");
        assert!(torch_err <= F32_TOL, "{name}: torch float32 rgb error {torch_err:e} > {F32_TOL:e}");
    }
}
