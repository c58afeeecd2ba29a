//! The executor's promises, checked with the GPU's counters on a golden Ray-Patch case: a scene is encoded
//! once; rendering again at the same size reuses the plan (no buffer, no pipeline, one submit); encoding
//! another scene of the same size reuses the encode plan (one submit, only the scene's own tensors
//! allocated) and leaves earlier scenes as they were; transient buffers are shared; the debug mode reads back
//! every op.

use std::path::Path;
use std::sync::Arc;

use raypatch_engine::{Gpu, GpuOptions, Model, Output, Outputs, Region, Request};

fn case(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/golden").join(name)
}

#[test]
fn rendering_again_allocates_and_compiles_nothing() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::load(gpu.clone(), case("rpsrt_k4").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("rpsrt_k4").join("scene.safetensors")).unwrap();
    let encoded = model.encode(&scene.inputs).unwrap();
    let first = encoded.render(&scene.targets, Outputs::default()).unwrap();
    let before = gpu.counters();
    let second = encoded.render(&scene.targets, Outputs::default()).unwrap();
    let after = gpu.counters();
    assert_eq!(first.get(Output::Rgb), second.get(Output::Rgb));
    assert_eq!(after.buffers_created, before.buffers_created, "a second render created buffers");
    assert_eq!(after.pipelines_compiled, before.pipelines_compiled, "a second render compiled pipelines");
    assert_eq!(after.submits, before.submits + 1, "a render is one submit");
    assert_eq!(encoded.cached_render_plans(), 1);
}

#[test]
fn pipelines_are_shared_between_plans() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::load(gpu.clone(), case("rpsrt_k4").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("rpsrt_k4").join("scene.safetensors")).unwrap();
    model.encode(&scene.inputs).unwrap();
    let compiled = gpu.counters().pipelines_compiled;
    // Another scene builds nothing: no new pipeline either.
    model.encode(&scene.inputs).unwrap();
    assert_eq!(gpu.counters().pipelines_compiled, compiled);
}

#[test]
fn encoding_again_reuses_the_plan_and_keeps_each_scene_its_own() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::load(gpu.clone(), case("rpsrt_k4").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("rpsrt_k4").join("scene.safetensors")).unwrap();
    let first = model.encode(&scene.inputs).unwrap();
    let first_frame = first.render(&scene.targets, Outputs::default()).unwrap();
    // Another scene of the same size: the images turned upside down in value.
    let mut flipped = scene.inputs.clone();
    flipped.images.iter_mut().for_each(|v| *v = 1.0 - *v);
    let before = gpu.counters();
    let second = model.encode(&flipped).unwrap();
    let after = gpu.counters();
    assert_eq!(after.submits, before.submits + 1, "an encode is one submit");
    assert_eq!(
        after.buffers_created - before.buffers_created,
        1 + second.cached.len() as u64,
        "an encode of a size seen before creates only the scene's own tensors"
    );
    let second_frame = second.render(&scene.targets, Outputs::default()).unwrap();
    assert_ne!(first_frame.get(Output::Rgb), second_frame.get(Output::Rgb), "the second scene rendered the first");
    // The first scene still renders what it did: the second encode wrote the plan's tensors, not its own.
    first.clear_render_plans();
    let again = first.render(&scene.targets, Outputs::default()).unwrap();
    assert_eq!(first_frame.get(Output::Rgb), again.get(Output::Rgb));
}

#[test]
fn transient_buffers_are_shared() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::load(gpu.clone(), case("srt_k1").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("srt_k1").join("scene.safetensors")).unwrap();
    let encoded = model.encode(&scene.inputs).unwrap();
    // A first render of a smaller region packs the weights that the matmul kernel may keep in textures
    // (once per model, a plan each), so that the render counted below creates only its own plan's buffers.
    let corner = Request { outputs: Outputs::default(), region: Some(Region { x: 0, y: 0, width: 4, height: 4 }) };
    encoded.render(&scene.targets, corner).unwrap();
    let before = gpu.counters();
    encoded.render(&scene.targets, Outputs::default()).unwrap();
    let after = gpu.counters();
    let ops = encoded.profile_render(&scene.targets, Outputs::default()).unwrap().len();
    // Without sharing, every op's output would be a buffer of its own.
    let buffers = after.buffers_created - before.buffers_created;
    assert!(buffers * 2 < ops as u64, "{buffers} buffers for {ops} ops: intermediates are not shared");
}

#[test]
fn debug_mode_reads_back_every_op() {
    use raypatch_engine::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
    use raypatch_engine::plan::PlanBuilder;

    let gpu = Gpu::new(&GpuOptions::default()).expect("no GPU adapter");
    let mut b = PlanBuilder::new();
    let x = b.input("x", 2, 3);
    let y = b.transient("y", 2, 3);
    let z = b.output("z", 2, 3);
    let (xv, yv, zv) = (b.all(x), b.all(y), b.all(z));
    map_columns(&mut b, "sigmoid", MapColumnsArgs { x: xv, col: 0, out: yv, map: Map::Sigmoid });
    map_columns(&mut b, "copy", MapColumnsArgs { x: yv, col: 0, out: zv, map: Map::Identity });
    let plan = b.build(&gpu).unwrap();
    gpu.write(&plan.tensor(x), &[0.0, 1.0, -1.0, 2.0, -2.0, 10.0]);
    let outputs = plan.execute_debug(&gpu).unwrap();
    assert_eq!(outputs.len(), 2);
    assert_eq!((outputs[0].op.as_str(), outputs[0].tensor.as_str()), ("sigmoid", "y"));
    assert_eq!(outputs[0].data[0], 0.5);
    assert_eq!(outputs[1].data, outputs[0].data);
}
