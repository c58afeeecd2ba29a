//! f16 weight storage: every linear weight within f16's range is stored as f16 and the render stays close
//! to the float64 reference; a layer with a weight beyond that range (|w| > 65504, which f16 would turn
//! into infinity) is detected at load, kept in f32 and reported, and the render stays finite and as close.

use raypatch_bench::synthetic::{model_from_tensors, Tensor};
use raypatch_engine::{Gpu, GpuOptions, MatmulKernel, Model, Outputs};
use raypatch_engine::{KeptF32, LoadOptions, Output, Precision};
use raypatch_model::{LoadedModel, TensorFile};
use raypatch_reference::model::{Argument, ReferenceModel};
use std::sync::Arc;

use crate::common::max_abs_diff;
use crate::{golden_case, gpu};

/// rgb error of f16 weights against the float64 reference: f16 rounds each weight by up to 2^-11 relatively
/// (4.9e-4), 2^13 times f32's rounding; through the ~12 layers of the golden models that moved rgb by 2e-3
/// to 4e-3 (measured). 1e-2 leaves a margin and is still ~1000x the f32 engine's error.
const F16_TOL: f64 = 1e-2;

/// rgb error of f16 activations against the float64 reference: the inputs of each linear layer rounded like its
/// weights (another 2^-11 relatively; the products are summed in f32) moved rgb by 1.8e-3 to 5.2e-3 on the golden
/// models (measured on lavapipe, about f16 weights' error). 1.5e-2 leaves a margin of about 3.
const F16_ACTIVATIONS_TOL: f64 = 1.5e-2;

fn golden_tensors(case: &str) -> (serde_json::Value, Vec<Tensor>) {
    let file = TensorFile::open(&golden_case(case).join("model.safetensors")).unwrap();
    let config = serde_json::from_str(&file.metadata["config"]).unwrap();
    let tensors = file
        .keys()
        .filter(|k| !k.ends_with("num_batches_tracked"))
        .map(|k| (k.to_string(), file.shape(k).unwrap().to_vec(), file.f32(k).unwrap().data))
        .collect();
    (config, tensors)
}

/// Renders `loaded` with f16 weights; returns what was kept in f32 and the rgb error against the reference.
fn render_f16(loaded: &LoadedModel, case: &str) -> (Vec<KeptF32>, f64) {
    render_at(gpu(), Precision::F16Weights, loaded, case)
}

/// Renders `loaded` at `precision` on `gpu`; returns what was kept in f32 and the rgb error against the reference.
fn render_at(gpu: Arc<Gpu>, precision: Precision, loaded: &LoadedModel, case: &str) -> (Vec<KeptF32>, f64) {
    let scene = raypatch_model::load_scene(golden_case(case).join("scene.safetensors")).unwrap();
    let model = Model::from_loaded_with(gpu, loaded, &LoadOptions { precision }).unwrap();
    let rgb = model
        .encode(&scene.inputs)
        .unwrap()
        .render(&scene.targets, Outputs::default())
        .unwrap()
        .take(Output::Rgb)
        .expect("rgb");
    assert!(rgb.iter().all(|v| v.is_finite()), "{case}: non-finite rgb at {precision:?}");
    let reference = ReferenceModel::new(loaded, Argument::RoundedToF32).unwrap();
    let want = reference.render(&reference.encode(&scene.inputs).unwrap(), &scene.targets).unwrap();
    (model.weights_kept_f32().to_vec(), max_abs_diff(&rgb, &want.rgb))
}

fn has_f16() -> bool {
    let ok = gpu().features.contains(raypatch_engine::wgpu::Features::SHADER_F16);
    if !ok {
        eprintln!("{} has no shader-f16: f16 storage not tested", gpu().describe());
    }
    ok
}

#[test]
fn f16_weights_stay_close_to_the_reference() {
    let _memory = crate::sharing_memory();
    if !has_f16() {
        return;
    }
    for case in ["srt_k1", "rpsrt_k4", "rpsrt_k16"] {
        let loaded = raypatch_model::load_model(golden_case(case).join("model.safetensors")).unwrap();
        let (kept, err) = render_f16(&loaded, case);
        eprintln!("{case}: f16 weights, rgb error {err:.1e}");
        assert!(kept.is_empty(), "{case}: layers kept in f32: {kept:?}");
        assert!(err <= F16_TOL, "{case}: rgb error {err:e} with f16 weights > {F16_TOL:e}");
    }
}

/// f16 activations on the kernel they change (`MatmulKernel::Tiled`, the GPUs' own; forced here): the linear
/// layers' inputs rounded to f16 as they are staged add to f16 weights' error.
#[test]
fn f16_activations_stay_close_to_the_reference() {
    let _memory = crate::sharing_memory();
    if !has_f16() {
        return;
    }
    let tiled = Arc::new(Gpu::new(&GpuOptions { matmul: Some(MatmulKernel::Tiled), ..Default::default() }).unwrap());
    for case in ["srt_k1", "rpsrt_k4", "rpsrt_k16"] {
        let loaded = raypatch_model::load_model(golden_case(case).join("model.safetensors")).unwrap();
        let (kept, err) = render_at(tiled.clone(), Precision::F16Activations, &loaded, case);
        eprintln!("{case}: f16 activations, rgb error {err:.1e}");
        assert!(kept.is_empty(), "{case}: layers kept in f32: {kept:?}");
        assert!(err <= F16_ACTIVATIONS_TOL, "{case}: rgb error {err:e} with f16 activations > {F16_ACTIVATIONS_TOL:e}");
    }
}

#[test]
fn weights_beyond_f16_range_keep_their_layer_in_f32() {
    let _memory = crate::sharing_memory();
    if !has_f16() {
        return;
    }
    let case = "rpsrt_k4";
    let (config, mut tensors) = golden_tensors(case);
    // 65504 is f16's largest finite value; 65520 and above round to infinity. The large weights multiply
    // hidden units that are exactly zero (their pre-activation is -1e3: ReLU and GELU give 0), so the model
    // stays well-behaved, and a weight that became infinity would turn the output into NaN (inf · 0).
    let set = |tensors: &mut Vec<Tensor>, key: &str, f: &dyn Fn(&[usize], &mut Vec<f32>)| {
        let (_, shape, data) = tensors.iter_mut().find(|(k, _, _)| k == key).unwrap();
        f(shape, data);
    };
    let dead_unit_0 = |shape: &[usize], w: &mut Vec<f32>| w[..shape[1]].fill(0.0);
    let bias = |b: &mut Vec<f32>| b[0] = -1e3;
    for prefix in ["encoder.transformer.layers.0.1.fn.net", "encoder.transformer.layers.1.1.fn.net"] {
        set(&mut tensors, &format!("{prefix}.0.weight"), &dead_unit_0);
        set(&mut tensors, &format!("{prefix}.0.bias"), &|_, b| bias(b));
    }
    set(&mut tensors, "decoder_att.ray_predictor.input_mlp.0.weight", &dead_unit_0);
    set(&mut tensors, "decoder_att.ray_predictor.input_mlp.0.bias", &|_, b| bias(b));
    // Column 0 reads the dead unit.
    let column_0 =
        |value: f32| move |shape: &[usize], w: &mut Vec<f32>| (0..shape[0]).for_each(|r| w[r * shape[1]] = value);
    set(&mut tensors, "encoder.transformer.layers.0.1.fn.net.3.weight", &column_0(65504.0));
    set(&mut tensors, "encoder.transformer.layers.1.1.fn.net.3.weight", &column_0(-65520.0));
    set(&mut tensors, "decoder_att.ray_predictor.input_mlp.2.weight", &column_0(1e5));
    let (loaded, _) = model_from_tensors(&config, &tensors, "rpsrt_k4 with large weights").unwrap();
    let (kept, err) = render_f16(&loaded, case);
    eprintln!("large weights: kept in f32 {kept:?}, rgb error {err:.1e}");
    let names: Vec<&str> = kept.iter().map(|k| k.tensor.as_str()).collect();
    assert_eq!(
        names,
        ["encoder.transformer.layers.1.1.fn.net.3.weight", "decoder_att.ray_predictor.input_mlp.2.weight"]
    );
    assert_eq!((kept[0].max_abs, kept[1].max_abs), (65520.0, 1e5));
    assert!(err <= F16_TOL, "rgb error {err:e} with f16 weights > {F16_TOL:e}");
}

#[test]
fn f16_uploads_refuse_values_beyond_range() {
    let _memory = crate::sharing_memory();
    if !has_f16() {
        return;
    }
    let err = gpu().upload_f16("w", 2, 3, &[0.0, 1.0, 2.0, 3.0, 65520.0, 5.0]).unwrap_err().to_string();
    assert!(err.contains("w: element [1, 1] = 65520 is outside the f16 range"), "{err}");
    gpu().upload_f16("w", 1, 2, &[65504.0, -65504.0]).unwrap();
}
