//! The float64 reference of the whole model (`reference::model`), which the rest of this suite and the
//! benchmark harness measure the engine against, checked on every golden case (SRT, RP-SRT, OSRT, RP-OSRT,
//! DeFiNe, RP-DeFiNe):
//! - with float64 encoding arguments it is the float64 PyTorch run of the official model (`latent_f64`,
//!   `set_latent_f64`, `rgb_f64`, `logdepth_f64`, `segmentation_f64`): the same maths in the same precision,
//!   so only f64 rounding differs;
//! - with the arguments rounded to f32 (as torch float32 and the engine form them) it is within float32
//!   arithmetic error of the float32 PyTorch run and of the engine (latent, rgb, log-depth where the model has
//!   it, and OSRT's segmentation).

use std::path::{Path, PathBuf};

use raypatch_engine::{Output, Outputs};
use raypatch_reference::model::{Argument, ReferenceModel};
use safetensors::{Dtype, SafeTensors};

use crate::common::max_abs_diff;
use crate::{engine_model, golden_case};

/// Float64 against float64: both compute every sin/cos argument exactly (an f32·f32 product fits in an
/// f64), so what remains is f64 rounding (~1e-16) amplified through the network; 1e-9 leaves a wide margin
/// (~1e-14 is seen).
const F64_TOL: f64 = 1e-9;
/// The engine (and torch float32) against the reference with f32-rounded arguments: the golden tests'
/// tolerance (f32 arithmetic through ~10 layers; ~5e-6 is seen), for rgb and OSRT's segmentation (both in
/// [0, 1]).
const F32_TOL: f64 = 1e-4;
/// The same for the latent (SRT's tokens, OSRT's slots, DeFiNe's latents) and the log-depth (unbounded, as
/// latents are), relative to the largest magnitude, as the golden tests measure it.
const F32_LATENT_REL_TOL: f64 = 1e-4;

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

/// The relative error `max |got - want| / max |want|` (latents, log-depth: unbounded values).
fn relative(got: &[f64], want: &[f64]) -> f64 {
    max_diff(got, want) / max_abs(want)
}

/// The segmentation a case holds, `[views, height, width, slots]`: its slot count.
fn expected_slots(expected: &Path) -> Option<usize> {
    let file = raypatch_model::TensorFile::open(expected).unwrap();
    file.contains("segmentation").then(|| *file.f32("segmentation").unwrap().shape.last().unwrap())
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

        // The latent is OSRT's slots; the SRT encoder's tokens beneath them are the set latent.
        let mut errors = vec![("latent rel", relative(&encoded.latent, &f64_tensor(&expected, "latent_f64")))];
        assert_eq!(encoded.set_latent.is_some(), model.config.base() == "osrt", "{name}: set latent");
        if let Some(set_latent) = &encoded.set_latent {
            errors.push(("set latent rel", relative(set_latent, &f64_tensor(&expected, "set_latent_f64"))));
        }
        errors.push(("rgb", max_diff(&frame.rgb, &f64_tensor(&expected, "rgb_f64"))));
        if let Some(depth) = &frame.logdepth {
            errors.push(("log-depth rel", relative(depth, &f64_tensor(&expected, "logdepth_f64"))));
        }
        assert_eq!(frame.segmentation.is_some().then_some(frame.slots), expected_slots(&expected), "{name}: slots");
        if let Some(segmentation) = &frame.segmentation {
            errors.push(("segmentation", max_diff(segmentation, &f64_tensor(&expected, "segmentation_f64"))));
        }
        let summary: Vec<String> = errors.iter().map(|(what, err)| format!("{what} {err:.1e}")).collect();
        eprintln!("{name}: float64 reference vs float64 PyTorch: {}", summary.join(", "));
        for (what, err) in errors {
            assert!(err <= F64_TOL, "{name}: {what} error {err:e} > {F64_TOL:e}");
        }
    }
}

#[test]
fn engine_and_float32_pytorch_match_the_reference_with_f32_arguments() {
    let _memory = crate::sharing_memory();
    for dir in golden_cases() {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let expected = dir.join("expected.safetensors");
        let loaded = raypatch_model::load_model(dir.join("model.safetensors")).unwrap();
        let scene = raypatch_model::load_scene(dir.join("scene.safetensors")).unwrap();
        let reference = ReferenceModel::new(&loaded, Argument::RoundedToF32).unwrap();
        let want_scene = reference.encode(&scene.inputs).unwrap();
        let want = reference.render(&want_scene, &scene.targets).unwrap();

        let model = engine_model(&loaded);
        let encoded = model.encode(&scene.inputs).unwrap();
        let mut outputs = Outputs::default();
        if want.segmentation.is_some() {
            outputs = outputs.with(Output::Segmentation);
        }
        if want.logdepth.is_some() {
            outputs = outputs.with(Output::LogDepth);
        }
        let frame = encoded.render(&scene.targets, outputs).unwrap();
        // (what, engine error, torch float32 error, tolerance): the latent and log-depth relative, rgb and
        // segmentation (in [0, 1]) absolute.
        let latent_scale = max_abs(&want_scene.latent);
        let engine_latent = crate::gpu().read(&encoded.latent).unwrap();
        let mut errors = vec![(
            "latent rel",
            max_abs_diff(&engine_latent, &want_scene.latent) / latent_scale,
            max_abs_diff(&f32_tensor(&expected, "latent"), &want_scene.latent) / latent_scale,
            F32_LATENT_REL_TOL,
        )];
        errors.push((
            "rgb",
            max_abs_diff(frame.get(Output::Rgb).expect("rgb"), &want.rgb),
            max_abs_diff(&f32_tensor(&expected, "rgb"), &want.rgb),
            F32_TOL,
        ));
        if let Some(logdepth) = &want.logdepth {
            let scale = max_abs(logdepth);
            errors.push((
                "log-depth rel",
                max_abs_diff(frame.get(Output::LogDepth).expect("log-depth"), logdepth) / scale,
                max_abs_diff(&f32_tensor(&expected, "logdepth"), logdepth) / scale,
                F32_LATENT_REL_TOL,
            ));
        }
        if let Some(segmentation) = &want.segmentation {
            errors.push((
                "segmentation",
                max_abs_diff(frame.get(Output::Segmentation).expect("segmentation"), segmentation),
                max_abs_diff(&f32_tensor(&expected, "segmentation"), segmentation),
                F32_TOL,
            ));
        }
        let f32_vs_f64 = max_diff(&want.rgb, &f64_tensor(&expected, "rgb_f64"));
        let summary: Vec<String> = errors
            .iter()
            .map(|(what, engine, torch, _)| format!("{what} engine {engine:.1e}, torch f32 {torch:.1e}"))
            .collect();
        eprintln!(
            "{name}: vs the reference with f32 arguments: {}; rgb with f32 arguments vs f64 arguments {f32_vs_f64:.1e}",
            summary.join("; ")
        );
        for (what, engine, torch, tol) in errors {
            assert!(engine <= tol, "{name}: engine {what} error {engine:e} > {tol:e}");
            assert!(torch <= tol, "{name}: torch float32 {what} error {torch:e} > {tol:e}");
        }
    }
}
