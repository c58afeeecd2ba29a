//! The embedded API on the golden cases: cameras agree with each other and with the official ray code; a
//! region renders exactly the full render's pixels (rgb, log-depth, OSRT segmentation) while decoding only the
//! patches it needs, and so do row bands; only the requested outputs are computed; outputs a model lacks are an
//! error; rendering never re-encodes and reuses its plan; bad input is an error.
//!
//! Over 600 lines on purpose: one file for the API's promises, each a test that reads on its own.

use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DVec3, Vec3};
use raypatch::metrics::{psnr, ssim};
use raypatch::{
    Camera, CameraAxes, Engine, EngineOptions, Error, Image, InputView, Intrinsics, Output, Outputs, Precision,
    RayGrid, Region, Rendered, Request, SceneData,
};

/// Largest difference allowed between two ray directions that describe the same camera: both are rounded
/// from f64 to f32 (half an ulp, 6e-8) after f64 maths whose rounding differs by a few 1e-16.
const RAY_TOLERANCE: f32 = 1e-6;

/// How far a render in row bands may differ from one render: the same ops on fewer rows, but on a GPU a layer's
/// kernel and its K split follow its row count (`device::linear_variant`), so its sums may run in another order.
/// Another order of a K-term f32 sum moves it by about √K·u·Σ|x·w| (u = 2^-24; ~2.4e-6 of Σ|x·w| at K = 1536),
/// a few layers deep: 1e-5 of the output's magnitude. rgb is in [0, 1]: absolute (an H200 measured 1.9e-6 and
/// 2.9e-6). Log-depth is the raw pre-sigmoid channel, unbounded, so relative to its largest magnitude, as the
/// golden tests measure it (an H100 measured 1.48e-5 absolute on srt_k1_depth, whose log-depth reaches 7.26:
/// 2.0e-6). lavapipe's are the same sums. A wrong band or halo is off by far more.
const BAND_TOLERANCE: f32 = 1e-5;

fn golden(case: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/golden").join(case)
}

fn engine() -> Engine {
    Engine::new(EngineOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)")
}

fn max_ray_diff(a: &RayGrid, b: &RayGrid) -> f32 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    a.rays.iter().zip(&b.rays).map(|(x, y)| (*x - *y).abs().max_element()).fold(0.0, f32::max)
}

/// The official `get_camera_rays` (tools/reference/cameras.py), written out on the sensor plane in f64.
fn official_msn_rays(c_pos: DVec3, width: usize, height: usize) -> RayGrid {
    let (focal, sensor_width) = (0.035, 0.032);
    let c_dir = -c_pos / c_pos.length();
    let horizontal = c_dir.cross(DVec3::Z).normalize();
    let vertical = c_dir.cross(horizontal).normalize();
    let sensor_height = sensor_width / width as f64 * height as f64;
    let midpoint = |i: usize, n: usize, size: f64| {
        let edge = |e: usize| (-1.0 + 2.0 * e as f64 / n as f64) * size / 2.0;
        (edge(i) + edge(i + 1)) / 2.0
    };
    let mut directions = Vec::new();
    for i in 0..height {
        for j in 0..width {
            let plane = c_dir * focal
                + midpoint(j, width, sensor_width) * horizontal
                + midpoint(i, height, sensor_height) * vertical;
            directions.push(plane.normalize().as_vec3());
        }
    }
    RayGrid { width, height, rays: directions }
}

#[test]
fn msn_cameras_give_the_official_rays() {
    // The golden scenes' target rays were written by tools/reference/cameras.py (numpy, f64 then f32).
    for case in ["srt_k1", "rpsrt_k4", "rpsrt_k16"] {
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        for target in &data.targets {
            let c = &target.camera;
            let msn = Camera::msn(c.position(), c.width(), c.height()).unwrap();
            let err = max_ray_diff(&msn.rays(), &c.rays());
            assert!(err <= RAY_TOLERANCE, "{case}: MSN camera rays differ from tools/reference/cameras.py by {err:e}");
        }
    }
    for (pos, w, h) in [(DVec3::new(3.0, -4.0, 2.0), 7, 5), (DVec3::new(-1.5, 0.2, 9.0), 160, 120)] {
        let err = max_ray_diff(&Camera::msn(pos, w, h).unwrap().rays(), &official_msn_rays(pos, w, h));
        assert!(err <= RAY_TOLERANCE, "{w}x{h}: {err:e}");
    }
}

#[test]
fn one_camera_three_ways_gives_the_same_rays() {
    let pos = DVec3::new(5.0, 2.0, -1.5);
    let msn = Camera::msn(pos, 24, 16).unwrap();
    let official = official_msn_rays(pos, 24, 16);

    // The same camera as intrinsics and a pose, built here from the MSN look-at definition.
    let forward = (-pos).normalize();
    let right = forward.cross(DVec3::Z).normalize();
    let down = forward.cross(right);
    let opencv = DMat4::from_cols(right.extend(0.0), down.extend(0.0), forward.extend(0.0), pos.extend(1.0));
    let intrinsics =
        Intrinsics { width: 24, height: 16, fx: 0.035 / 0.032 * 24.0, fy: 0.035 / 0.032 * 24.0, cx: 12.0, cy: 8.0 };
    let pinhole_cv = Camera::pinhole(intrinsics, opencv, CameraAxes::OpenCv).unwrap();
    // OpenGL axes: y up and z backwards, i.e. the OpenCV y and z columns negated.
    let opengl = DMat4::from_cols(right.extend(0.0), (-down).extend(0.0), (-forward).extend(0.0), pos.extend(1.0));
    let pinhole_gl = Camera::pinhole(intrinsics, opengl, CameraAxes::OpenGl).unwrap();
    let explicit = Camera::from_rays(pos, official.clone()).unwrap();

    for (name, camera) in
        [("msn", &msn), ("pinhole OpenCV", &pinhole_cv), ("pinhole OpenGL", &pinhole_gl), ("rays", &explicit)]
    {
        let err = max_ray_diff(&camera.rays(), &official);
        assert!(err <= RAY_TOLERANCE, "{name}: rays differ from the official ones by {err:e}");
        assert_eq!(camera.position(), pos);
        assert_eq!((camera.width(), camera.height()), (24, 16));
    }
    let (k, pose) = msn.as_pinhole().unwrap();
    assert!((pose - opencv).abs().to_cols_array().iter().all(|d| *d < 1e-12));
    assert_eq!(k, intrinsics);
}

#[test]
fn bad_cameras_are_errors() {
    let k = Intrinsics::msn(8, 8);
    let pose = DMat4::from_translation(DVec3::new(0.0, 0.0, 5.0));
    let scaled = pose * DMat4::from_scale(DVec3::splat(1.1));
    let mirrored = pose * DMat4::from_scale(DVec3::new(1.0, 1.0, -1.0));
    let sheared = DMat4::from_mat3(DMat3::from_cols(DVec3::X, DVec3::new(0.3, 1.0, 0.0), DVec3::Z));
    for (what, m) in [("scaled", scaled), ("mirrored", mirrored), ("sheared", sheared)] {
        let err = Camera::pinhole(k, m, CameraAxes::OpenGl).unwrap_err().to_string();
        assert!(err.contains("not orthonormal"), "{what}: {err}");
    }
    let mut nan = pose;
    nan.w_axis.x = f64::NAN;
    assert!(Camera::pinhole(k, nan, CameraAxes::OpenCv).unwrap_err().to_string().contains("NaN"));
    assert!(Camera::msn(DVec3::new(0.0, 0.0, 3.0), 8, 8).unwrap_err().to_string().contains("up axis"));
    assert!(Camera::msn(DVec3::ZERO, 8, 8).is_err());
    assert!(Camera::msn(DVec3::X, 0, 8).unwrap_err().to_string().contains("empty"));
    let grid = RayGrid { width: 2, height: 1, rays: vec![Vec3::X, Vec3::new(f32::INFINITY, 0.0, 0.0)] };
    assert!(Camera::from_rays(DVec3::X, grid).unwrap_err().to_string().contains("ray 1"));
    let short = RayGrid { width: 2, height: 2, rays: vec![Vec3::X] };
    assert!(Camera::from_rays(DVec3::X, short).is_err());
}

/// Patches each side of a region that the Ray-Patch conv decoder's receptive field can reach, at most.
const HALO: usize = 3;

/// Regions of a `width`×`height` image: single pixels in the corners, strips along each border, interior
/// boxes that do not start on a patch boundary, and the whole image.
fn regions(width: usize, height: usize) -> Vec<Region> {
    let r = |x, y, w, h| Region { x, y, width: w, height: h };
    vec![
        r(0, 0, 1, 1),
        r(width - 1, height - 1, 1, 1),
        r(width - 1, 0, 1, 1),
        r(0, height - 3, width, 3),
        r(width - 5, 0, 5, height),
        r(width / 3 + 1, height / 2 - 1, 5, 3),
        r(width / 2, height / 4, width / 2 - 3, height / 2),
        r(0, 0, width, height),
    ]
}

/// The `region` of a row-major single-channel map `width` columns wide.
fn crop_map(map: &[f32], width: usize, region: Region) -> Vec<f32> {
    (region.y..region.y + region.height)
        .flat_map(|y| map[y * width + region.x..y * width + region.x + region.width].iter().copied())
        .collect()
}

/// The `region` of a row-major `[height, width, channels]` map `width` columns wide.
fn crop_channels(values: &[f32], width: usize, channels: usize, region: Region) -> Vec<f32> {
    (region.y..region.y + region.height)
        .flat_map(|y| {
            let start = (y * width + region.x) * channels;
            values[start..start + region.width * channels].iter().copied()
        })
        .collect()
}

/// Channels of `output` in a render (one per slot for the segmentation).
fn channels(rendered: &Rendered, output: Output) -> usize {
    rendered.outputs.iter().find(|r| r.output == output).map(|r| r.channels).expect("output rendered")
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn regions_render_the_full_renders_pixels_and_decode_only_their_patches() {
    let engine = engine();
    let cases = ["srt_k1", "srt_k1_depth", "rpsrt_k2", "rpsrt_k4", "rpsrt_k4_patchrays", "rpsrt_k8", "rpsrt_k16"];
    for case in cases {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let camera = &data.targets[0].camera;
        let (width, height, k) = (camera.width(), camera.height(), model.patch_size());
        let outputs =
            if model.has_depth() { Outputs::of(&[Output::Rgb, Output::LogDepth]) } else { Outputs::default() };
        let full_request = Request { outputs, region: None };
        let full = scene.render(camera, &full_request).unwrap();
        let full_rgb = full.rgb().unwrap();
        let full_stats = scene.render_stats(camera, &full_request).unwrap();
        assert_eq!(full_stats.queries, width * height / (k * k), "{case}: one query per patch");

        for region in regions(width, height) {
            let request = Request { outputs, region: Some(region) };
            let part = scene.render(camera, &request).unwrap();
            assert_eq!(part.region, region);
            // The conv decoder sums in the same order wherever a pixel lies, so the pixels are equal; allow
            // one f32 rounding of the largest value in case a driver reassociates.
            let err = max_diff(part.rgb().unwrap().data(), full_rgb.crop(region).unwrap().data());
            assert!(err <= 1e-6, "{case} {region:?}: region rgb differs from the full render by {err:e}");
            if let (Some(d), Some(full_d)) = (part.logdepth(), full.logdepth()) {
                let want = crop_map(full_d, width, region);
                assert_eq!(max_diff(d, &want), 0.0, "{case} {region:?}: log-depth");
            }

            // What was decoded: for SRT exactly the region's pixels; for Ray-Patch the covering patches
            // plus at most HALO patches each side (the conv decoder's receptive field), clipped to the image.
            let stats = scene.render_stats(camera, &request).unwrap();
            let span = |start: usize, len: usize, size: usize| {
                let (first, last) = (start / k, (start + len - 1) / k);
                let (lo, hi) =
                    if k == 1 { (first, last) } else { (first.saturating_sub(HALO), (last + HALO).min(size / k - 1)) };
                hi + 1 - lo
            };
            let most = span(region.x, region.width, width) * span(region.y, region.height, height);
            assert!(stats.queries <= most, "{case} {region:?}: {} queries, at most {most} needed", stats.queries);
            assert!(stats.queries >= region.width.div_ceil(k) * region.height.div_ceil(k), "{case} {region:?}");
            assert!(stats.pixels == stats.queries * k * k && stats.queries <= full_stats.queries);
            if k == 1 {
                assert_eq!(stats.queries, region.width * region.height, "{case} {region:?}");
            }
        }
        // The corner pixel decodes fewer patches than the image has, once the image is more than a halo wide.
        if (width / k).max(height / k) > HALO + 1 {
            let corner = Request { outputs, region: Some(Region { x: 0, y: 0, width: 1, height: 1 }) };
            assert!(scene.render_stats(camera, &corner).unwrap().queries < full_stats.queries, "{case}");
        }
    }
}

#[test]
fn the_halo_is_needed() {
    // Without the halo the region's border pixels would see the conv decoder's zero padding: check that a
    // region render does differ from a full render of the region's own patches taken as an image.
    let engine = engine();
    let model = engine.load(golden("rpsrt_k4").join("model.safetensors")).unwrap();
    let data = SceneData::load(golden("rpsrt_k4").join("scene.safetensors")).unwrap();
    let scene = model.encode(&data.inputs).unwrap();
    let camera = &data.targets[0].camera;
    let region = Region { x: 16, y: 8, width: 16, height: 16 };
    let full = scene.render(camera, &Request::default()).unwrap().rgb().unwrap().crop(region).unwrap();
    // The region's patches alone: a camera whose rays are exactly those of the region.
    let rays = camera.rays();
    let directions = (region.y..region.y + region.height)
        .flat_map(|y| rays.rays[y * rays.width + region.x..y * rays.width + region.x + region.width].to_vec())
        .collect();
    let alone = Camera::from_rays(camera.position(), RayGrid { width: 16, height: 16, rays: directions }).unwrap();
    let no_halo = scene.render(&alone, &Request::default()).unwrap().rgb().unwrap();
    assert!(max_diff(no_halo.data(), full.data()) > 1e-3, "the region's patches alone already give its pixels");
}

#[test]
fn only_requested_outputs_are_computed() {
    let engine = engine();
    let model = engine.load(golden("srt_k1_depth").join("model.safetensors")).unwrap();
    let data = SceneData::load(golden("srt_k1_depth").join("scene.safetensors")).unwrap();
    let scene = model.encode(&data.inputs).unwrap();
    let camera = &data.targets[0].camera;
    let request = |rgb: bool, logdepth: bool| {
        let outputs = [(rgb, Output::Rgb), (logdepth, Output::LogDepth)].into_iter().filter(|(on, _)| *on);
        Request { outputs: outputs.fold(Outputs::NONE, |set, (_, o)| set.with(o)), region: None }
    };
    let labels = |r: &Request| scene.engine_scene().render_op_labels(&camera.target_views(), *r).unwrap();
    let dispatches = |r: &Request| {
        scene.render(camera, r).unwrap(); // build and warm the plan
        let before = engine.counters().dispatches;
        let out = scene.render(camera, r).unwrap();
        (engine.counters().dispatches - before, out)
    };

    let (rgb_only, rgb_out) = dispatches(&request(true, false));
    let (both, both_out) = dispatches(&request(true, true));
    let (depth_only, depth_out) = dispatches(&request(false, true));
    assert_eq!(both, rgb_only + 2, "log-depth costs one dispatch and its readout");
    assert_eq!(depth_only, rgb_only, "dropping rgb drops the sigmoid");
    let has = |r: &Request, op: &str| labels(r).iter().any(|l| l == op);
    assert!(has(&request(true, false), "sigmoid") && !has(&request(true, false), "logdepth"));
    assert!(!has(&request(false, true), "sigmoid") && has(&request(false, true), "logdepth"));
    assert!(rgb_out.logdepth().is_none() && depth_out.rgb().is_none());
    assert_eq!(rgb_out.get(Output::Rgb), both_out.get(Output::Rgb));
    assert_eq!(depth_out.logdepth(), both_out.logdepth());
    let stats = scene.render_stats(camera, &request(true, false)).unwrap();
    assert_eq!(stats.dispatches as u64, rgb_only, "a render runs its plan's dispatches and nothing else");
    let err = scene.render(camera, &request(false, false)).unwrap_err().to_string();
    assert!(err.contains("nothing to render"), "{err}");
}

#[test]
fn rendering_reuses_the_encoded_scene_and_the_plan() {
    let engine = engine();
    let model = engine.load(golden("rpsrt_k4").join("model.safetensors")).unwrap();
    let data = SceneData::load(golden("rpsrt_k4").join("scene.safetensors")).unwrap();
    let scene = model.encode(&data.inputs).unwrap();
    let camera = &data.targets[0].camera;
    let labels = scene.engine_scene().render_op_labels(&camera.target_views(), Outputs::default()).unwrap();
    assert!(
        labels.iter().all(|l| !l.starts_with("encoder.") && !l.contains("to_kv")),
        "a render plan re-encodes or re-projects keys/values"
    );

    let interior = |x| Request { region: Some(Region { x, y: 12, width: 6, height: 6 }), ..Request::default() };
    scene.render(camera, &Request::default()).unwrap();
    scene.render(camera, &interior(17)).unwrap();
    let (plans, before) = (scene.cached_plans(), engine.counters());
    // Another camera of the same size, and the same-sized region elsewhere: the same two plans. (Given rays, as
    // the scene's camera: a pinhole camera's rays are made on the GPU, by plans of their own.)
    let msn = Camera::msn(DVec3::new(-6.0, 5.0, 2.0), camera.width(), camera.height()).unwrap();
    let other = Camera::from_rays(msn.position(), msn.rays()).unwrap();
    scene.render(&other, &Request::default()).unwrap();
    scene.render(camera, &interior(21)).unwrap();
    let after = engine.counters();
    assert_eq!(scene.cached_plans(), plans);
    assert_eq!(after.buffers_created, before.buffers_created, "a same-size render created buffers");
    assert_eq!(after.pipelines_compiled, before.pipelines_compiled, "a same-size render compiled pipelines");
    assert_eq!(after.submits, before.submits + 2, "each render is one submit");

    // Another size: a new plan, but no pipeline is keyed on a render's size (rows and K splits are params).
    let larger = Camera::msn(DVec3::new(-6.0, 5.0, 2.0), camera.width() * 2, camera.height() + 8).unwrap();
    scene.render(&larger, &Request::default()).unwrap();
    assert_eq!(engine.counters().pipelines_compiled, after.pipelines_compiled, "another size compiled pipelines");
}

/// A pinhole camera's rays are made on the GPU (nothing per pixel is uploaded), bit-equal to the host's: its
/// render is the render of the same rays given, pixel for pixel, whole, in a region, and several views at once.
#[test]
fn a_pinhole_camera_renders_the_pixels_of_its_rays_given() {
    for case in ["rpsrt_k4", "srt_k1_depth", "rposrt_k8", "define"] {
        let engine = engine();
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let (width, height) = (data.targets[0].camera.width(), data.targets[0].camera.height());
        let pinholes: Vec<Camera> = [DVec3::new(4.0, -3.0, 2.5), DVec3::new(-2.0, 5.5, 1.0)]
            .iter()
            .map(|p| Camera::msn(*p, width, height).unwrap().orbited(17.0))
            .collect();
        let given: Vec<Camera> =
            pinholes.iter().map(|c| Camera::from_rays(c.position(), c.rays_of(model.ray_kind())).unwrap()).collect();
        let region = Request { region: Some(Region { x: 3, y: 5, width: 9, height: 7 }), ..Request::default() };
        for request in [Request::default(), region] {
            let (a, b) = (scene.render(&pinholes[0], &request).unwrap(), scene.render(&given[0], &request).unwrap());
            for output in model.outputs().iter() {
                assert_eq!(a.get(output), b.get(output), "{case}: {} of a pinhole camera", output.name());
            }
        }
        let all = Request::default();
        let (a, b) = (scene.render_batch(&pinholes, &all).unwrap(), scene.render_batch(&given, &all).unwrap());
        for (a, b) in a.iter().zip(&b) {
            assert_eq!(a.get(Output::Rgb), b.get(Output::Rgb), "{case}: a batch of pinhole cameras");
        }
    }
}

/// The first render's pipelines compile while the GPU encodes: a render of the inputs' size compiles none.
#[test]
fn the_first_renders_pipelines_compile_during_the_encode() {
    for case in ["rpsrt_k4", "srt_k1_depth", "rposrt_k8", "define"] {
        let engine = engine();
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let before = engine.counters().pipelines_compiled;
        let (width, height) = (data.inputs[0].camera.width(), data.inputs[0].camera.height());
        let camera = Camera::msn(data.targets[0].camera.position(), width, height).unwrap();
        scene.render(&camera, &Request::default()).unwrap();
        assert_eq!(engine.counters().pipelines_compiled, before, "{case}: the first render compiled pipelines");
    }
}

/// The engine's precision applies to every model it loads: f16 weights (and, on the GPUs' kernel, activations)
/// move the render by f16's rounding (tests/stress/f16.rs bounds it against the float64 model), no more.
#[test]
fn models_load_at_the_engines_precision() {
    let render = |precision| {
        let engine = Engine::new(EngineOptions { precision, ..Default::default() }).unwrap();
        let model = match engine.load(golden("rpsrt_k4").join("model.safetensors")) {
            Err(e) if e.to_string().contains("need shader-f16") => return None,
            loaded => loaded.unwrap(),
        };
        let data = SceneData::load(golden("rpsrt_k4").join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let rendered = scene.render(&data.targets[0].camera, &Request::default()).unwrap();
        Some(rendered.get(Output::Rgb).unwrap().to_vec())
    };
    let f32_rgb = render(Precision::F32).expect("f32 needs no feature");
    for precision in [Precision::F16Weights, Precision::F16Activations] {
        let Some(rgb) = render(precision) else {
            eprintln!("the adapter has no shader-f16: {precision:?} not tested");
            return;
        };
        let diff = max_diff(&rgb, &f32_rgb);
        assert!(diff > 0.0 && diff < 1e-2, "{precision:?}: rgb moved by {diff} from f32's");
    }
}

#[test]
fn bad_requests_and_views_are_errors() {
    let engine = engine();
    let model = engine.load(golden("rpsrt_k4").join("model.safetensors")).unwrap();
    let data = SceneData::load(golden("rpsrt_k4").join("scene.safetensors")).unwrap();
    let scene = model.encode(&data.inputs).unwrap();
    fn message<T>(r: raypatch::Result<T>) -> String {
        r.err().expect("bad input accepted").to_string()
    }

    assert!(message(model.encode(&[])).contains("no input view"));
    let small = InputView {
        image: Image::new(16, 8, vec![0.5; 16 * 8 * 3]).unwrap(),
        camera: Camera::msn(DVec3::new(5.0, 0.0, 1.0), 16, 8).unwrap(),
    };
    let mixed = [data.inputs[0].clone(), small.clone()];
    assert!(message(model.encode(&mixed)).contains("same size"));
    let mismatched = InputView { camera: data.inputs[0].camera.clone(), ..small.clone() };
    assert!(message(model.encode(&[mismatched])).contains("camera is for a 32x24 image"));
    let bright = InputView { image: Image::new(16, 8, vec![1.5; 16 * 8 * 3]).unwrap(), ..small };
    assert!(message(model.encode(&[bright])).contains("expected [0, 1]"));
    assert!(matches!(Image::new(1, 1, vec![0.0, f32::NAN, 0.0]), Err(Error::Image { .. })));

    let camera = &data.targets[0].camera;
    let outside = Request { region: Some(Region { x: 40, y: 0, width: 9, height: 4 }), ..Request::default() };
    assert!(message(scene.render(camera, &outside)).contains("not inside the 48x32"));
    let odd = Camera::msn(DVec3::new(5.0, 1.0, 2.0), 50, 32).unwrap();
    assert!(message(scene.render(&odd, &Request::default())).contains("not divisible by the model's patch size k=4"));
    let depth = Request { outputs: Outputs::of(&[Output::Rgb, Output::LogDepth]), region: None };
    assert!(message(scene.render(camera, &depth)).contains("no depth channel"));
}

#[test]
fn frames_folders_read_nerf_cameras() {
    // Two frames whose poses are MSN cameras written with NeRF's OpenGL axes.
    let dir = std::env::temp_dir().join(format!("raypatch-api-frames-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (w, h) = (32usize, 24usize);
    let positions = [DVec3::new(6.0, 1.0, 2.0), DVec3::new(-3.0, 5.0, 1.0)];
    let mut frames = Vec::new();
    for (i, pos) in positions.iter().enumerate() {
        let (_, cv) = Camera::msn(*pos, w, h).unwrap().as_pinhole().unwrap();
        let gl = DMat4::from_cols(cv.x_axis, -cv.y_axis, -cv.z_axis, cv.w_axis);
        let rows: Vec<Vec<f64>> = (0..4).map(|r| gl.row(r).to_array().to_vec()).collect();
        frames.push(serde_json::json!({ "file_path": format!("./r_{i}"), "transform_matrix": rows }));
        // Multiples of 1/255 survive the 8-bit PNG exactly.
        let pixels: Vec<f32> = (0..w * h * 3).map(|v| (40 * (v % 7)) as f32 / 255.0).collect();
        Image::new(w, h, pixels).unwrap().save_png(dir.join(format!("r_{i}.png"))).unwrap();
    }
    let fov_x = 2.0 * (0.016f64 / 0.035).atan();
    let transforms = serde_json::json!({ "camera_angle_x": fov_x, "frames": frames });
    std::fs::write(dir.join("transforms.json"), transforms.to_string()).unwrap();

    let data = SceneData::load(&dir).unwrap();
    assert_eq!((data.inputs.len(), data.targets.len()), (2, 2));
    for (view, pos) in data.inputs.iter().zip(positions) {
        let err = max_ray_diff(&view.camera.rays(), &official_msn_rays(pos, w, h));
        assert!(err <= RAY_TOLERANCE, "NeRF pose rays differ from the MSN camera's by {err:e}");
        assert_eq!(view.image.pixel(1, 0), [120.0 / 255.0, 160.0 / 255.0, 200.0 / 255.0]);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn metrics_match_torchmetrics() {
    // Values from torchmetrics 1.9 on these images, as float64 tensors (data_range=1.0): the functional
    // structural_similarity_index_measure, and PeakSignalNoiseRatio, computed once with
    //   a[c,i,j] = ((7i + 13j + 5c) % 17) / 16;  b = 0.6 a + 0.4 ((3i + 11j + 2c) % 19) / 18  (rounded to f32)
    const SSIM: f64 = 0.7905090211217978;
    const PSNR: f64 = 15.29788875579834;
    let (w, h) = (23, 17);
    let mut a = Vec::new();
    let mut b = Vec::new();
    for i in 0..h {
        for j in 0..w {
            for c in 0..3 {
                let x = ((i * 7 + j * 13 + c * 5) % 17) as f64 / 16.0;
                a.push(x as f32);
                b.push((0.6 * x + 0.4 * (((i * 3 + j * 11 + c * 2) % 19) as f64 / 18.0)) as f32);
            }
        }
    }
    let (a, b) = (Image::new(w, h, a).unwrap(), Image::new(w, h, b).unwrap());
    let s = ssim(&b, &a).unwrap();
    assert!((s - SSIM).abs() < 1e-12, "SSIM {s} vs torchmetrics {SSIM}");
    // torchmetrics returns PSNR as float32.
    let p = psnr(&b, &a).unwrap();
    assert!((p - PSNR).abs() < 1e-5, "PSNR {p} vs torchmetrics {PSNR}");
    assert!(psnr(&a, &a).unwrap().is_infinite());
    let tiny = Image::new(4, 4, vec![0.0; 48]).unwrap();
    assert!(ssim(&tiny, &tiny).unwrap_err().to_string().contains("at least 6x6"));
    assert!(psnr(&a, &tiny).unwrap_err().to_string().contains("different sizes"));
}

#[test]
fn orbits_turn_explicit_rays_like_pinhole_cameras() {
    let data = SceneData::load(golden("srt_k1").join("scene.safetensors")).unwrap();
    let given = &data.targets[0].camera;
    let msn = Camera::msn(given.position(), given.width(), given.height()).unwrap();
    for degrees in [30.0, 90.0, 200.0] {
        let (a, b) = (given.orbited(degrees), msn.orbited(degrees));
        assert!((a.position() - b.position()).length() < 1e-12);
        assert!(max_ray_diff(&a.rays(), &b.rays()) <= 2.0 * RAY_TOLERANCE, "{degrees}°");
    }
}

#[test]
fn renders_too_large_for_one_buffer_run_in_bands_with_the_same_pixels() {
    let unlimited = engine();
    for case in ["srt_k1_depth", "rpsrt_k2", "rpsrt_k4", "rpsrt_k8", "rpsrt_k16"] {
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let model = unlimited.load(golden(case).join("model.safetensors")).unwrap();
        // Targets large enough that the render's buffers, not the encoder's, are the largest.
        let (width, height) = if model.patch_size() == 1 { (256, 192) } else { (512, 384) };
        let camera = &Camera::msn(data.targets[0].camera.position(), width, height).unwrap();
        let outputs =
            if model.has_depth() { Outputs::of(&[Output::Rgb, Output::LogDepth]) } else { Outputs::default() };
        let full_request = Request { outputs, region: None };
        let scene = model.encode(&data.inputs).unwrap();
        let full = scene.render(camera, &full_request).unwrap();
        let one = scene.render_stats(camera, &full_request).unwrap();
        assert_eq!(one.bands, 1, "{case}");

        // Ray-Patch: an engine whose buffers may hold one view's rgb, less than the full-resolution conv
        // features, so that the render must run in bands. SRT: 2/5 of its largest buffer, a query chunk,
        // which shrinks to fit instead.
        let bands_needed = model.patch_size() > 1;
        let limit = if bands_needed { (width * height * 3 * 4) as u64 } else { one.largest_buffer_bytes * 2 / 5 };
        let limited = Engine::new(EngineOptions { max_buffer_bytes: Some(limit), ..Default::default() }).unwrap();
        let model = limited.load(golden(case).join("model.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let inner = Region { x: 1, y: 5, width: width - 2, height: height - 10 };
        for region in [None, Some(inner)] {
            let request = Request { outputs, region };
            let banded = scene.render(camera, &request).unwrap();
            let stats = scene.render_stats(camera, &request).unwrap();
            assert!(stats.largest_buffer_bytes <= limit, "{case} {region:?}: {stats:?}");
            assert_eq!(stats.bands > 1, bands_needed, "{case} {region:?}: {stats:?}");
            let region = region.unwrap_or(full.region);
            assert_eq!(banded.region, region, "{case}");
            let want = full.rgb().unwrap().crop(region).unwrap();
            let err = max_diff(banded.rgb().unwrap().data(), want.data());
            assert!(err <= BAND_TOLERANCE, "{case} {region:?}: banded rgb differs from one render by {err:e}");
            if let (Some(d), Some(full_d)) = (banded.logdepth(), full.logdepth()) {
                let want = crop_map(full_d, camera.width(), region);
                let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1.0);
                let err = max_diff(d, &want) / scale;
                assert!(err <= BAND_TOLERANCE, "{case} {region:?}: log-depth differs by {err:e} of its magnitude");
            }
        }
    }
}

#[test]
fn a_buffer_limit_nothing_fits_under_is_an_error_naming_the_buffer() {
    let tiny = Engine::new(EngineOptions { max_buffer_bytes: Some(2048), ..Default::default() }).unwrap();
    let case = golden("rpsrt_k4");
    let message = match tiny.load(case.join("model.safetensors")) {
        Err(e) => e.to_string(),
        Ok(model) => {
            let data = SceneData::load(case.join("scene.safetensors")).unwrap();
            let rendered =
                model.encode(&data.inputs).and_then(|s| s.render(&data.targets[0].camera, &Request::default()));
            match rendered {
                Ok(_) => panic!("a 2 KiB buffer limit cannot fit this model"),
                Err(e) => e.to_string(),
            }
        }
    };
    assert!(message.contains("bytes in one buffer, more than the 2048 bytes one buffer may have"), "{message}");
}

/// The OSRT golden cases: OSRT light fields, and RP-OSRT at k=8 and k=4 (the latter with patch rays).
const OSRT_CASES: [&str; 4] = ["osrt", "osrt_iters3_ln", "rposrt_k8", "rposrt_k4_patchrays"];

/// Requests of rgb and segmentation, of segmentation alone and of rgb alone.
fn osrt_output_sets() -> [Outputs; 3] {
    [Outputs::of(&[Output::Rgb, Output::Segmentation]), Outputs::of(&[Output::Segmentation]), Outputs::default()]
}

/// Checks that `part` holds exactly `outputs`, each equal to the same pixels of `full` (a render of the whole
/// `width`-wide image with every output `part` has) within one f32 rounding.
fn check_same_pixels(what: &str, part: &Rendered, full: &Rendered, width: usize, outputs: Outputs) {
    let region = part.region;
    for output in [Output::Rgb, Output::Segmentation] {
        let (got, want) = (part.get(output), full.get(output));
        if !outputs.contains(output) {
            assert!(got.is_none(), "{what}: {} rendered but not asked for", output.title());
            continue;
        }
        let c = channels(full, output);
        assert_eq!(channels(part, output), c, "{what}: {} channels", output.title());
        let want = crop_channels(want.expect("the full render has every output"), width, c, region);
        let err = max_diff(got.expect("asked for"), &want);
        assert!(err <= BAND_TOLERANCE, "{what}: {} differs from the full render's by {err:e}", output.title());
    }
}

#[test]
fn osrt_regions_render_the_full_renders_rgb_and_segmentation() {
    let engine = engine();
    for case in OSRT_CASES {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let camera = &data.targets[0].camera;
        let (width, height, k) = (camera.width(), camera.height(), model.patch_size());
        assert!(model.outputs().contains(Output::Segmentation) && !model.has_depth(), "{case}");
        let both = Outputs::of(&[Output::Rgb, Output::Segmentation]);
        let full = scene.render(camera, &Request { outputs: both, region: None }).unwrap();
        let full_stats = scene.render_stats(camera, &Request { outputs: both, region: None }).unwrap();
        assert_eq!(full_stats.queries, width * height / (k * k), "{case}: one query per patch");

        for region in regions(width, height) {
            for outputs in osrt_output_sets() {
                let request = Request { outputs, region: Some(region) };
                let part = scene.render(camera, &request).unwrap();
                assert_eq!(part.region, region);
                check_same_pixels(&format!("{case} {region:?} {outputs:?}"), &part, &full, width, outputs);

                // Decoded: the region's pixels for OSRT; for RP-OSRT the covering patches plus at most HALO
                // patches each side (the conv decoder's receptive field; the segmentation's bilinear resize
                // reads one patch further at most), clipped to the image.
                let stats = scene.render_stats(camera, &request).unwrap();
                let span = |start: usize, len: usize, size: usize| {
                    let (first, last) = (start / k, (start + len - 1) / k);
                    let (lo, hi) = if k == 1 {
                        (first, last)
                    } else {
                        (first.saturating_sub(HALO), (last + HALO).min(size / k - 1))
                    };
                    hi + 1 - lo
                };
                let most = span(region.x, region.width, width) * span(region.y, region.height, height);
                let what = format!("{case} {region:?} {outputs:?}: {} queries", stats.queries);
                assert!(stats.queries <= most, "{what}, at most {most} needed");
                assert!(stats.queries >= region.width.div_ceil(k) * region.height.div_ceil(k), "{what}");
                assert!(stats.pixels == stats.queries * k * k && stats.queries <= full_stats.queries, "{what}");
                if k == 1 {
                    assert_eq!(stats.queries, region.width * region.height, "{what}");
                }
            }
        }
        if (width / k).max(height / k) > HALO + 1 {
            for outputs in osrt_output_sets() {
                let corner = Request { outputs, region: Some(Region { x: 0, y: 0, width: 1, height: 1 }) };
                assert!(scene.render_stats(camera, &corner).unwrap().queries < full_stats.queries, "{case}");
            }
        }
    }
}

#[test]
fn osrt_renders_too_large_for_one_buffer_run_in_bands_with_the_same_pixels() {
    let unlimited = engine();
    for case in ["osrt", "rposrt_k8", "rposrt_k4_patchrays"] {
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let model = unlimited.load(golden(case).join("model.safetensors")).unwrap();
        let k = model.patch_size();
        let (width, height) = if k == 1 { (192, 128) } else { (512, 384) };
        let position = data.targets[0].camera.position();
        // rposrt_k4_patchrays: a camera given by its patch rays, as the case's scene gives them.
        let camera = &if data.targets[0].camera.pixels_per_ray() == k && k > 1 {
            Camera::from_patch_rays(position, Camera::msn(position, width / k, height / k).unwrap().rays(), k).unwrap()
        } else {
            Camera::msn(position, width, height).unwrap()
        };
        let all = Request { outputs: Outputs::of(&[Output::Rgb, Output::Segmentation]), region: None };
        let scene = model.encode(&data.inputs).unwrap();
        let full = scene.render(camera, &all).unwrap();
        assert_eq!(scene.render_stats(camera, &all).unwrap().bands, 1, "{case}");

        // RP-OSRT: buffers that may hold one view's rgb, unpadded: less than the rgb output (rows padded to 4
        // floats), the segmentation (5 or 6 slots, padded to 8) and the full-resolution conv features. OSRT: 24
        // bytes a pixel, less than the segmentation (32), more than the rgb (16) and the encoder's input.
        let limit = (width * height * if k == 1 { 24 } else { 12 }) as u64;
        let limited = Engine::new(EngineOptions { max_buffer_bytes: Some(limit), ..Default::default() }).unwrap();
        let model = limited.load(golden(case).join("model.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let inner = Region { x: 1, y: 5, width: width - 2, height: height - 10 };
        // The whole image with both outputs; an inner region with the segmentation alone (RP-OSRT: a
        // different halo, that of the weights' bilinear resize only).
        let [both, segmentation, _] = osrt_output_sets();
        for (outputs, region) in [(both, None), (segmentation, Some(inner))] {
            let request = Request { outputs, region };
            let banded = scene.render(camera, &request).unwrap();
            let stats = scene.render_stats(camera, &request).unwrap();
            let what = format!("{case} {region:?} {outputs:?}");
            assert!(stats.largest_buffer_bytes <= limit, "{what}: {stats:?}");
            assert!(stats.bands > 1, "{what}: {stats:?}");
            assert_eq!(banded.region, region.unwrap_or(full.region), "{what}");
            check_same_pixels(&format!("{what} banded"), &banded, &full, width, outputs);
        }
    }
}

#[test]
fn osrt_renders_compute_only_the_requested_outputs() {
    let engine = engine();
    for case in OSRT_CASES {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let camera = &data.targets[0].camera;
        let ray_patch = model.patch_size() > 1;
        let request = |outputs: &[Output]| Request { outputs: Outputs::of(outputs), region: None };
        // Op labels without the query-chunk suffix ("[0..384]").
        let labels = |r: &Request| -> Vec<String> {
            let labels = scene.engine_scene().render_op_labels(&camera.target_views(), *r).unwrap();
            labels.iter().map(|l| l.split('[').next().unwrap().to_string()).collect()
        };
        let dispatches = |r: &Request| {
            scene.render(camera, r).unwrap(); // build and warm the plan
            let before = engine.counters().dispatches;
            let out = scene.render(camera, r).unwrap();
            let n = engine.counters().dispatches - before;
            assert_eq!(scene.render_stats(camera, r).unwrap().dispatches as u64, n, "{case} {r:?}");
            (n, out)
        };
        let (rgb_r, seg_r, both_r) =
            (request(&[Output::Rgb]), request(&[Output::Segmentation]), request(&[Output::Rgb, Output::Segmentation]));
        let (rgb_only, rgb_out) = dispatches(&rgb_r);
        let (seg_only, seg_out) = dispatches(&seg_r);
        let (both, both_out) = dispatches(&both_r);

        // rgb alone: no segmentation read back, and (RP-OSRT) no bilinear resize of the slot weights.
        let rgb_labels = labels(&rgb_r);
        assert!(rgb_labels.iter().any(|l| l == "sigmoid"), "{case}: {rgb_labels:?}");
        assert!(!rgb_labels.iter().any(|l| l.contains("segmentation")), "{case}: {rgb_labels:?}");
        assert_eq!(rgb_out.outputs.len(), 1, "{case}: rgb alone rendered {:?}", rgb_out.outputs);
        assert!(rgb_out.get(Output::Segmentation).is_none());
        // Segmentation alone stops at the mixing weights: no slot mix, render MLP, conv decoder or sigmoid.
        let seg_labels = labels(&seg_r);
        let image_work = |l: &String| {
            l.starts_with("decoder_att.render_mlp")
                || l.starts_with("decoder_rp.")
                || l.contains("slot_mix")
                || l == "sigmoid"
        };
        assert!(!seg_labels.iter().any(image_work), "{case}: a segmentation render records {seg_labels:?}");
        assert!(seg_labels.iter().any(|l| l == "decoder_att.mixing_block.weights"), "{case}: {seg_labels:?}");
        assert_eq!(seg_labels.iter().any(|l| l == "segmentation"), ray_patch, "{case}: {seg_labels:?}");
        assert!(seg_only < rgb_only, "{case}: segmentation alone {seg_only} dispatches, rgb alone {rgb_only}");
        assert!(seg_out.rgb().is_none() && seg_out.outputs.len() == 1, "{case}");
        // Both: OSRT's mixing weights are the segmentation itself (read out); RP-OSRT adds their bilinear resize.
        assert_eq!(both, rgb_only + 1 + u64::from(ray_patch), "{case}: rgb + segmentation dispatches");
        assert_eq!(rgb_out.get(Output::Rgb), both_out.get(Output::Rgb), "{case}: rgb");
        assert_eq!(seg_out.get(Output::Segmentation), both_out.get(Output::Segmentation), "{case}: segmentation");
    }
}

#[test]
fn outputs_a_model_lacks_are_an_error() {
    let engine = engine();
    for (case, lacking, why) in [
        ("srt_k1", Output::Segmentation, "no object slots"),
        ("rpsrt_k4", Output::Segmentation, "no object slots"),
        ("srt_k1", Output::LogDepth, "no depth channel"),
        ("osrt", Output::LogDepth, "no depth channel"),
        ("osrt", Output::Depth, "no depth channel"),
        ("rposrt_k8", Output::LogDepth, "no depth channel"),
        ("rposrt_k4_patchrays", Output::Depth, "no depth channel"),
    ] {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        assert!(!model.outputs().contains(lacking), "{case}");
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let camera = &data.targets[0].camera;
        for outputs in [Outputs::of(&[lacking]), Outputs::default().with(lacking)] {
            let request = Request { outputs, region: None };
            let err = scene.render(camera, &request).unwrap_err().to_string();
            assert!(err.contains(lacking.title()) && err.contains(why), "{case} {outputs:?}: {err}");
            assert!(scene.render_stats(camera, &request).is_err(), "{case} {outputs:?}");
            assert!(scene.engine_scene().render_op_labels(&camera.target_views(), request).is_err());
        }
        // The scene still renders what the model has.
        let fine = scene.render(camera, &Request { outputs: model.outputs(), region: None }).unwrap();
        assert_eq!(fine.outputs.len(), model.outputs().iter().count(), "{case}");
    }
}

#[test]
fn depth_is_exp_of_logdepth() {
    let engine = engine();
    let model = engine.load(golden("srt_k1_depth").join("model.safetensors")).unwrap();
    assert!(model.outputs().contains(Output::Depth) && model.outputs().contains(Output::LogDepth));
    let data = SceneData::load(golden("srt_k1_depth").join("scene.safetensors")).unwrap();
    let scene = model.encode(&data.inputs).unwrap();
    let camera = &data.targets[0].camera;
    let both =
        scene.render(camera, &Request { outputs: Outputs::of(&[Output::LogDepth, Output::Depth]), region: None });
    let both = both.unwrap();
    let (logdepth, depth) = (both.logdepth().unwrap(), both.get(Output::Depth).unwrap());
    assert_eq!(depth.len(), camera.width() * camera.height());
    // The GPU's exp against f64's: a few f32 roundings apart.
    let err = logdepth
        .iter()
        .zip(depth)
        .map(|(l, d)| ((*d as f64 - (*l as f64).exp()) / (*l as f64).exp()).abs())
        .fold(0.0, f64::max);
    assert!(err <= 2e-6, "depth differs from exp(log-depth) by a relative {err:e}");
    assert!(logdepth.iter().any(|l| l.abs() > 0.5), "log-depth too close to 0 for the check to mean anything");

    // Depth alone: no log-depth copied out, no sigmoid, the same depth.
    let alone = Request { outputs: Outputs::of(&[Output::Depth]), region: None };
    let depth_only = scene.render(camera, &alone).unwrap();
    assert!(depth_only.logdepth().is_none() && depth_only.rgb().is_none());
    assert_eq!(depth_only.get(Output::Depth), Some(depth));
    let labels = scene.engine_scene().render_op_labels(&camera.target_views(), alone).unwrap();
    assert!(labels.iter().any(|l| l == "depth"), "{labels:?}");
    assert!(!labels.iter().any(|l| l == "logdepth" || l == "sigmoid"), "{labels:?}");
    // And in a region.
    let region = Region { x: 3, y: 5, width: 7, height: 4 };
    let part = scene.render(camera, &Request { region: Some(region), ..alone }).unwrap();
    assert_eq!(part.get(Output::Depth).unwrap(), crop_map(depth, camera.width(), region).as_slice());
}

#[test]
fn segmentation_is_slot_weights_summing_to_one() {
    let engine = engine();
    for case in OSRT_CASES {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let slots = match &model.config().family {
            raypatch::raypatch_model::Family::Osrt(c) => c.slot_attention.num_slots,
            _ => panic!("{case}: not an OSRT model"),
        };
        let request = Request { outputs: Outputs::of(&[Output::Segmentation]), region: None };
        // The scene's target cameras, and one orbited to a view no target has.
        let mut cameras: Vec<Camera> = data.targets.iter().map(|t| t.camera.clone()).collect();
        cameras.push(cameras[0].orbited(75.0));
        let mut winners = vec![false; slots];
        for (i, camera) in cameras.iter().enumerate() {
            let out = scene.render(camera, &request).unwrap();
            assert_eq!(channels(&out, Output::Segmentation), slots, "{case}: one channel per slot");
            let seg = out.get(Output::Segmentation).unwrap();
            assert_eq!(seg.len(), camera.width() * camera.height() * slots);
            // OSRT: a softmax over the slots; RP-OSRT: bilinear mixes (weights summing to 1) of such rows.
            let mut worst = 0.0f32;
            for row in seg.chunks_exact(slots) {
                assert!(row.iter().all(|w| (0.0..=1.0).contains(w)), "{case} camera {i}: weights {row:?}");
                worst = worst.max((row.iter().sum::<f32>() - 1.0).abs());
                let best = (0..slots).max_by(|a, b| row[*a].total_cmp(&row[*b])).unwrap();
                winners[best] = true;
            }
            assert!(worst <= 1e-5, "{case} camera {i}: a pixel's slot weights sum to 1 ± {worst:e}");
        }
        let won = winners.iter().filter(|w| **w).count();
        assert!(won > 1, "{case}: one slot wins every pixel, the check says little");
    }
}

const DEFINE_CASES: [&str; 3] = ["define", "rpdefine_k16", "rpdefine_k16_patchrays_in60x88"];

/// Each of DeFiNe's outputs in a region equals the full render's pixels (within one f32 rounding), rendered
/// alone or with the others.
#[test]
fn define_regions_render_the_full_renders_pixels() {
    let engine = engine();
    let all = Outputs::of(&[Output::Rgb, Output::LogDepth, Output::Depth]);
    for case in DEFINE_CASES {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        assert_eq!(model.outputs(), all, "{case}");
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let camera = &data.targets[0].camera;
        let width = camera.width();
        let full = scene.render(camera, &Request { outputs: all, region: None }).unwrap();
        for region in regions(width, camera.height()) {
            for outputs in [all, Outputs::of(&[Output::Depth]), Outputs::of(&[Output::Rgb, Output::LogDepth])] {
                let part = scene.render(camera, &Request { outputs, region: Some(region) }).unwrap();
                for output in Output::ALL {
                    let what = format!("{case} {region:?} {outputs:?} {}", output.title());
                    let got = part.get(output);
                    if !outputs.contains(output) {
                        assert!(got.is_none(), "{what}: rendered but not asked for");
                        continue;
                    }
                    let c = channels(&full, output);
                    let want = crop_channels(full.get(output).unwrap(), width, c, region);
                    let err = max_diff(got.expect("asked for"), &want);
                    assert!(err <= 1e-6, "{what}: differs from the full render's by {err:e}");
                }
            }
        }
    }
}

/// A DeFiNe render runs only the heads its outputs need: rgb alone never touches the depth decoder, depth
/// alone never the rgb decoder, and each gives the same values as a render of both.
#[test]
fn define_renders_run_only_the_heads_asked_for() {
    let engine = engine();
    for case in DEFINE_CASES {
        let model = engine.load(golden(case).join("model.safetensors")).unwrap();
        let data = SceneData::load(golden(case).join("scene.safetensors")).unwrap();
        let scene = model.encode(&data.inputs).unwrap();
        let camera = &data.targets[0].camera;
        let request = |outputs: &[Output]| Request { outputs: Outputs::of(outputs), region: None };
        let labels = |r: &Request| scene.engine_scene().render_op_labels(&camera.target_views(), *r).unwrap();
        let (rgb, depth, both) =
            (request(&[Output::Rgb]), request(&[Output::LogDepth, Output::Depth]), request(&Output::ALL[..3]));
        let reads = |labels: &[String], head: &str| labels.iter().any(|l| l.contains(head));
        let rgb_labels = labels(&rgb);
        assert!(
            reads(&rgb_labels, "decoder_att_rgb") && !reads(&rgb_labels, "decoder_att_d."),
            "{case}: {rgb_labels:?}"
        );
        assert!(!reads(&rgb_labels, "decoder_rp_d.") && !reads(&rgb_labels, "logdepth"), "{case}: {rgb_labels:?}");
        let depth_labels = labels(&depth);
        assert!(reads(&depth_labels, "decoder_att_d.") && !reads(&depth_labels, "decoder_att_rgb"), "{case}");
        assert!(
            !reads(&depth_labels, "decoder_rp_rgb") && !reads(&depth_labels, "sigmoid"),
            "{case}: {depth_labels:?}"
        );
        // Both: the two heads, sharing only the patch rays made from full-resolution rays.
        let shared: Vec<&String> = rgb_labels.iter().filter(|l| depth_labels.contains(l)).collect();
        assert!(shared.iter().all(|l| l.as_str() == "patch_rays"), "{case}: {shared:?}");
        assert_eq!(labels(&both).len(), rgb_labels.len() + depth_labels.len() - shared.len(), "{case}");

        let (rgb_out, depth_out, both_out) = (
            scene.render(camera, &rgb).unwrap(),
            scene.render(camera, &depth).unwrap(),
            scene.render(camera, &both).unwrap(),
        );
        assert_eq!(rgb_out.get(Output::Rgb), both_out.get(Output::Rgb), "{case}: rgb");
        for output in [Output::LogDepth, Output::Depth] {
            assert_eq!(depth_out.get(output), both_out.get(output), "{case}: {}", output.title());
        }
        // Depth is the official sigmoid scaled to 0.1..10, and exp(log-depth) within a few f32 roundings.
        let (logdepth, depth) = (both_out.logdepth().unwrap(), both_out.get(Output::Depth).unwrap());
        for (&l, &d) in logdepth.iter().zip(depth) {
            assert!((0.1..=10.0).contains(&d), "{case}: depth {d} outside the official range");
            let rel = (d as f64 - (l as f64).exp()).abs() / d as f64;
            assert!(rel <= 2e-6, "{case}: depth {d} is not exp(log-depth {l}) (relative {rel:e})");
        }
    }
}

/// The official encoder joins the ResNet features at 1/4 size with the rays resized to H/4 x W/4: input sides
/// not divisible by 4 are refused, naming the size and the reason.
#[test]
fn define_inputs_must_have_sides_divisible_by_4() {
    let gpu = std::sync::Arc::new(raypatch_engine::Gpu::new(&Default::default()).unwrap());
    let model = raypatch_engine::Model::load(gpu, golden("define").join("model.safetensors")).unwrap();
    let inputs = raypatch_model::load_scene(golden("define").join("scene.safetensors")).unwrap().inputs;
    let (h, w) = (inputs.height - 2, inputs.width);
    let crop = |v: &[f32]| -> Vec<f32> {
        v.chunks(inputs.height * w * 3).flat_map(|view| view[..h * w * 3].iter().copied()).collect()
    };
    let odd = raypatch_model::InputViews {
        height: h,
        images: crop(&inputs.images),
        rays: crop(&inputs.rays),
        ..inputs.clone()
    };
    let err = model.encode(&odd).err().expect("an input height not divisible by 4 is refused").to_string();
    assert!(err.contains(&format!("{w}x{h}")) && err.contains("divisible by 4"), "{err}");
}
