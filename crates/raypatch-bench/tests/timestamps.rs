//! GPU timestamps (gpu.rs / plan.rs), which the harness times renders with: per plan and per op, labelled in
//! plan order, none when off. Skipped (with a message) on adapters without timestamp queries.

use std::path::Path;
use std::sync::Arc;

use raypatch_engine::gpu::TimestampMode;
use raypatch_engine::{Gpu, GpuOptions, Model, Outputs};

#[test]
fn timestamps_cover_plans_and_ops() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    if gpu.set_timestamps(TimestampMode::Ops).is_err() {
        eprintln!("{} has no timestamp queries inside passes: nothing to check", gpu.describe());
        return;
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/golden/rpsrt_k4");
    let model = Model::load(gpu.clone(), dir.join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(dir.join("scene.safetensors")).unwrap();
    let encoded = model.encode(&scene.inputs).unwrap();
    let encode_times = gpu.take_timestamps().unwrap().expect("the encode plan was timed");
    assert!(!encode_times.ops.is_empty());
    assert!(gpu.take_timestamps().unwrap().is_none(), "timestamps are taken once");

    encoded.render(&scene.targets, Outputs::default()).unwrap();
    let times = gpu.take_timestamps().unwrap().expect("the render was timed");
    gpu.set_timestamps(TimestampMode::Off).unwrap();
    let profiled = encoded.profile_render(&scene.targets, Outputs::default()).unwrap();
    let labels: Vec<&str> = profiled.iter().map(|(label, _)| label.as_str()).collect();
    let timed: Vec<&str> = times.ops.iter().map(|o| o.label.as_str()).collect();
    assert_eq!(timed, labels, "one time per op, in plan order");
    assert!(times.ops.iter().all(|o| o.kernel.contains('.')), "kernels are named shader.entry");
    // The ops' spans tile the pass: they add up to its total (each rounded to a nanosecond).
    let sum: u128 = times.ops.iter().map(|o| o.time.as_nanos()).sum();
    let total = times.total.as_nanos();
    assert!(sum.abs_diff(total) <= times.ops.len() as u128, "ops sum to {sum} ns, the pass took {total} ns");
    assert!(gpu.take_timestamps().unwrap().is_none(), "no timestamps when off");

    gpu.set_timestamps(TimestampMode::Plan).unwrap();
    encoded.render(&scene.targets, Outputs::default()).unwrap();
    let plan_times = gpu.take_timestamps().unwrap().expect("the render was timed");
    assert!(plan_times.ops.is_empty() && plan_times.total.as_nanos() > 0);
}
