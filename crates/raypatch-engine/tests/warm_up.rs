//! Loading a model compiles the pipelines of its first encode and render in the background, at the size its
//! config was made for (the golden `rpsrt_k8`: a Ray-Patch decoder resizing to 32x48): nothing is compiled
//! twice however soon the first encode comes, an encode gives the same latent whether or not the warm-up was
//! done, and a model dropped during its warm-up lets go of the GPU once the warm-up is done.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use raypatch_engine::{Gpu, GpuOptions, Model, Output, Outputs};
use raypatch_model::InputViews;

fn model_file() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/golden/rpsrt_k8/model.safetensors")
}

fn gpu() -> Arc<Gpu> {
    Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)"))
}

/// One input view of the model's nominal 32x48, seen from `(6, 2, 3)` towards the origin (its values only need
/// to be the same in every encode).
fn nominal_inputs() -> InputViews {
    let (height, width) = (32, 48);
    let position = [6.0f32, 2.0, 3.0];
    let norm = position.iter().map(|v| v * v).sum::<f32>().sqrt();
    let mut rays = Vec::with_capacity(height * width * 3);
    for y in 0..height {
        for x in 0..width {
            let off = [(x as f32 / width as f32 - 0.5) * 0.4, (y as f32 / height as f32 - 0.5) * 0.3, 0.0];
            let d: Vec<f32> = (0..3).map(|c| -position[c] / norm + off[c]).collect();
            let n = d.iter().map(|v| v * v).sum::<f32>().sqrt();
            rays.extend(d.iter().map(|v| v / n));
        }
    }
    let images = (0..height * width * 3).map(|i| (i % 17) as f32 / 16.0).collect();
    InputViews { count: 1, height, width, images, camera_pos: position.to_vec(), rays }
}

/// The scene file's target views: 32x48, the nominal size.
fn targets() -> raypatch_model::TargetViews {
    let path = model_file().with_file_name("scene.safetensors");
    raypatch_model::load_scene(path).unwrap().targets
}

#[test]
fn the_load_compiles_the_first_encodes_and_renders_pipelines() {
    let gpu = gpu();
    let before = gpu.counters().pipelines_compiled;
    let model = Model::load(gpu.clone(), model_file()).unwrap();
    model.finish_warm_up();
    let warmed = gpu.counters().pipelines_compiled;
    assert!(warmed > before, "the load compiled no pipeline");
    let scene = model.encode(&nominal_inputs()).unwrap();
    scene.render(&targets(), Outputs::default()).unwrap();
    assert_eq!(gpu.counters().pipelines_compiled, warmed, "the first encode and render of the nominal size compiled");
}

#[test]
fn an_encode_right_after_the_load_waits_for_the_warm_up_and_gives_the_same_latent() {
    // Each on a GPU of its own: one encodes while its warm-up runs, one once it is done.
    let run = |wait: bool| {
        let gpu = gpu();
        let model = Model::load(gpu.clone(), model_file()).unwrap();
        if wait {
            model.finish_warm_up();
        }
        let scene = model.encode(&nominal_inputs()).unwrap();
        let latent = gpu.read(&scene.latent).unwrap();
        let rgb = scene.render(&targets(), Outputs::default()).unwrap().get(Output::Rgb).unwrap().to_vec();
        (latent, rgb, gpu.counters().pipelines_compiled)
    };
    let (soon, done) = (run(false), run(true));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&soon.0), bits(&done.0), "the latent differs");
    assert_eq!(bits(&soon.1), bits(&done.1), "the render differs");
    // Where the warm-up was done, each distinct pipeline compiled once: as many where the encode came at once.
    assert_eq!(soon.2, done.2, "a pipeline compiled twice (or one less)");
}

#[test]
fn a_model_dropped_during_its_warm_up_lets_go_of_the_gpu() {
    let gpu = gpu();
    drop(Model::load(gpu.clone(), model_file()).unwrap());
    // The warm-up thread holds the GPU until it is done; then nothing but this test does.
    let deadline = Instant::now() + Duration::from_secs(600);
    while Arc::strong_count(&gpu) > 1 {
        assert!(Instant::now() < deadline, "the warm-up of a dropped model never finished");
        std::thread::sleep(Duration::from_millis(10));
    }
    // Its pipelines were compiled and serve the next model of the file.
    let compiled = gpu.counters().pipelines_compiled;
    assert!(compiled > 0);
    let model = Model::load(gpu.clone(), model_file()).unwrap();
    model.encode(&nominal_inputs()).unwrap().render(&targets(), Outputs::default()).unwrap();
    assert_eq!(gpu.counters().pipelines_compiled, compiled);
}
