//! The executor's promises, checked with the GPU's counters on a golden Ray-Patch case: a scene is encoded
//! once; rendering again at the same size reuses the plan (no buffer, no pipeline, one submit); transient
//! buffers are shared; the debug mode reads back every op.

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
    // A second scene builds a new encode plan but needs no new pipeline.
    model.encode(&scene.inputs).unwrap();
    assert_eq!(gpu.counters().pipelines_compiled, compiled);
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
