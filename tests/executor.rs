//! The executor's promises, checked with the GPU's counters on a golden Ray-Patch case: a scene is encoded
//! once; rendering again at the same size reuses the plan (no buffer, no pipeline, one submit); encoding
//! another scene of the same size reuses the encode plan (one submit, only the scene's own tensors
//! allocated) and leaves earlier scenes as they were; transient buffers are shared; the debug mode reads back
//! every op; a sequence of renders keeps one in flight with nothing allocated once it runs; views come apart as
//! they are read; no NaN reaches a kernel, and one the kernels make is caught and its op named.

use std::path::Path;
use std::sync::Arc;

use raypatch_engine::{Gpu, GpuOptions, Model, Output, Outputs, Region, Request};
use raypatch_model::TargetRays;

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

#[test]
fn a_sequence_keeps_a_render_in_flight_and_allocates_nothing_after_its_second() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::load(gpu.clone(), case("rpsrt_k4").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("rpsrt_k4").join("scene.safetensors")).unwrap();
    let encoded = model.encode(&scene.inputs).unwrap();
    let alone = encoded.render(&scene.targets.view(0), Outputs::default()).unwrap();
    let batches = || (0..6).map(|_| scene.targets.view(0));
    let mut frames = encoded.render_sequence(batches(), Outputs::default().into());
    // The first two batches: the second goes to the GPU before the first is read, on a staging of its own.
    for frame in frames.by_ref().take(2) {
        assert_eq!(frame.unwrap()[0].get(Output::Rgb), alone.get(Output::Rgb));
    }
    let before = gpu.counters();
    let rest: Vec<_> = frames.map(|f| f.unwrap().remove(0)).collect();
    let after = gpu.counters();
    assert_eq!(rest.len(), 4);
    assert!(rest.iter().all(|f| f.get(Output::Rgb) == alone.get(Output::Rgb)), "a render in flight changed pixels");
    assert_eq!(after.buffers_created, before.buffers_created, "renders in a sequence created buffers");
    assert_eq!(after.bytes_allocated, before.bytes_allocated, "renders in a sequence allocated");
    assert_eq!(after.submits, before.submits + 3, "a submit per render (the next was submitted already)");
}

#[test]
fn views_come_apart_as_read_and_non_finite_inputs_never_reach_a_kernel() {
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::load(gpu.clone(), case("rpsrt_k4").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("rpsrt_k4").join("scene.safetensors")).unwrap();
    let encoded = model.encode(&scene.inputs).unwrap();
    let mut two = scene.targets.view(0);
    two.append(scene.targets.view(0));
    let joined = encoded.render(&two, Outputs::default()).unwrap();
    let each = encoded.render_each(&two, Outputs::default()).unwrap();
    let rgb = joined.get(Output::Rgb).unwrap();
    assert_eq!(each.len(), 2);
    assert_eq!([each[0].get(Output::Rgb).unwrap(), each[1].get(Output::Rgb).unwrap()].concat(), rgb);

    let TargetRays::Given(rays) = &mut two.rays else { panic!("a scene file's rays are values") };
    rays[7] = f32::NAN;
    let submits = gpu.counters().submits;
    let err = encoded.render(&two, Outputs::default()).unwrap_err().to_string();
    assert!(err.contains("target_rays") && err.contains("finite"), "{err}");
    assert_eq!(gpu.counters().submits, submits, "a render with a NaN ray was submitted");
}

/// A render's readout: the window of each view, packed densely, and the flag raised by a NaN or an infinity
/// inside the window only.
#[test]
fn the_readout_packs_the_window_and_flags_non_finite_values_in_it() {
    use raypatch_engine::kernels::readout::{read_region, ReadoutArgs};
    use raypatch_engine::plan::PlanBuilder;

    let gpu = Gpu::new(&GpuOptions::default()).expect("no GPU adapter");
    let (views, height, width, cols) = (2, 3, 4, 3);
    let mut b = PlanBuilder::new();
    let x = b.input("x", views * height * width, cols);
    let out = b.output("out", (views * height * width * cols).div_ceil(4), 4);
    let window = b.input("window", 1, 4);
    let flag = b.output("flag", 1, 1);
    let args =
        ReadoutArgs { x: b.all(x), views, height, width, out: b.all(out), window: b.all(window), flag: b.all(flag) };
    read_region(&mut b, "readout", args);
    let plan = b.build(&gpu).unwrap();
    let run = |values: &[f32]| {
        gpu.write(&plan.tensor(x), values);
        // Rows 1..3 and columns 1..3 of each 3x4 view.
        gpu.write(&plan.tensor(window), &[1u32, 1, 2, 2].map(f32::from_bits));
        gpu.write(&plan.tensor(flag), &[0.0]);
        plan.execute(&gpu);
        let packed = gpu.read(&plan.tensor(out)).unwrap();
        (packed, gpu.read(&plan.tensor(flag)).unwrap()[0].to_bits())
    };
    let mut values: Vec<f32> = (0..views * height * width * cols).map(|i| i as f32).collect();
    let (packed, raised) = run(&values);
    let pixel = |v: usize, r: usize, c: usize| ((v * height + r) * width + c) * cols;
    let want: Vec<f32> = (0..views)
        .flat_map(|v| {
            (1..3).flat_map(move |r| (1..3).flat_map(move |c| (0..cols).map(move |j| (pixel(v, r, c) + j) as f32)))
        })
        .collect();
    assert_eq!(&packed[..want.len()], &want[..]);
    assert_eq!(raised, 0, "finite values raised the flag");
    values[pixel(1, 0, 0)] = f32::NAN;
    assert_eq!(run(&values).1, 0, "a NaN outside the window raised the flag");
    values[pixel(1, 2, 1) + 2] = f32::INFINITY;
    assert_eq!(run(&values).1, 1, "an infinity in the window did not raise the flag");
}

/// A pinhole camera's rays are made on the GPU where it makes them bit-equal to the host's (lavapipe does),
/// else on the host (`GpuOptions::rays_on_host` stands for such a GPU): one or the other, the same pixels, and
/// only the GPU's plan has the rays op and uploads no ray.
#[test]
fn pinhole_rays_made_on_the_gpu_or_the_host_render_the_same_pixels() {
    let render = |rays_on_host: bool| {
        let gpu = Arc::new(Gpu::new(&GpuOptions { rays_on_host, ..GpuOptions::default() }).expect("no GPU adapter"));
        let model = Model::load(gpu.clone(), case("rposrt_k8").join("model.safetensors")).unwrap();
        let scene = raypatch_model::load_scene(case("rposrt_k8").join("scene.safetensors")).unwrap();
        let encoded = model.encode(&scene.inputs).unwrap();
        let (height, width) = (scene.inputs.height, scene.inputs.width);
        let cameras = [glam::DVec3::new(4.0, -3.0, 2.5), glam::DVec3::new(-1.0, 5.0, 3.0)]
            .map(|p| raypatch::Camera::msn(p, width, height).unwrap().target_views_of(model.config.ray_kind()));
        let [mut targets, second] = cameras;
        targets.append(second);
        assert!(matches!(targets.rays, TargetRays::Pinhole(_)));
        let labels = encoded.render_op_labels(&targets, Outputs::default()).unwrap();
        let stats = encoded.render_stats(&targets, Outputs::default()).unwrap();
        let frame = encoded.render(&targets, Outputs::default()).unwrap();
        (frame, labels.iter().any(|l| l == "target_rays"), stats.staging_bytes)
    };
    let (on_gpu, gpu_op, gpu_staging) = render(false);
    let (on_host, host_op, host_staging) = render(true);
    assert!(gpu_op && !host_op, "the rays op runs where the GPU makes the rays, and only there");
    assert!(gpu_staging < host_staging, "the GPU's rays were uploaded ({gpu_staging} >= {host_staging} bytes)");
    for output in [Output::Rgb, Output::Segmentation] {
        assert_eq!(on_gpu.get(output), on_host.get(output), "{}", output.name());
    }
}

/// A pinhole camera's rays are those of its own kind, made on the GPU or the host alike, whatever the model's
/// kind: the benchmark's look-at cameras make unit directions for every family, DeFiNe (unit-depth points)
/// included, and the GPU once made such a camera's rays as the model's kind from terms made for the other
/// (no normalisation, no camera centre), 2e-2 off in DeFiNe's rgb. One model of each kind, the camera of the
/// other kind; two views, the second's camera of the model's own kind.
#[test]
fn a_pinhole_camera_of_another_kind_than_the_models_renders_its_own_rays_on_the_gpu() {
    use raypatch_model::RayKind;
    for case_name in ["define", "srt_k1"] {
        let render = |rays_on_host: bool| {
            let gpu =
                Arc::new(Gpu::new(&GpuOptions { rays_on_host, ..GpuOptions::default() }).expect("no GPU adapter"));
            let model = Model::load(gpu.clone(), case(case_name).join("model.safetensors")).unwrap();
            let scene = raypatch_model::load_scene(case(case_name).join("scene.safetensors")).unwrap();
            let encoded = model.encode(&scene.inputs).unwrap();
            let (height, width) = (scene.targets.rays_height, scene.targets.rays_width);
            let own = model.config.ray_kind();
            let other = match own {
                RayKind::UnitDirection => RayKind::UnitDepthPoint,
                RayKind::UnitDepthPoint => RayKind::UnitDirection,
            };
            let camera = |p: glam::DVec3, kind| raypatch::Camera::msn(p, width, height).unwrap().target_views_of(kind);
            let mut targets = camera(glam::DVec3::new(4.0, -3.0, 2.5), other);
            targets.append(camera(glam::DVec3::new(-1.0, 5.0, 3.0), own));
            let TargetRays::Pinhole(cameras) = &targets.rays else { panic!("not pinhole cameras") };
            assert_eq!(cameras.iter().map(|c| c.kind).collect::<Vec<_>>(), [other, own]);
            let labels = encoded.render_op_labels(&targets, Outputs::default()).unwrap();
            (encoded.render(&targets, Outputs::default()).unwrap(), labels.iter().any(|l| l == "target_rays"))
        };
        let ((on_gpu, gpu_op), (on_host, host_op)) = (render(false), render(true));
        assert!(gpu_op && !host_op, "{case_name}: the rays op runs where the GPU makes the rays, and only there");
        let (a, b) = (on_gpu.get(Output::Rgb).unwrap(), on_host.get(Output::Rgb).unwrap());
        let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(a == b, "{case_name}: the GPU's rays render rgb {worst:e} from the host's");
    }
}
