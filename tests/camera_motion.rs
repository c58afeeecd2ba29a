//! Camera motions, interpolation and resizing (src/motion.rs), the conventions they rest on (z-up MultiShapeNet
//! and y-up NeRF scenes, OpenCV and OpenGL axes), and rendering a path ([`Scene::render_path`]): the same pixels
//! as rendering each camera alone, one plan for the path.

use glam::{DMat3, DMat4, DVec3};
use raypatch::{
    fit_pinhole, interpolate, motion_path, resized, scene_centre, up_axis, Camera, CameraAxes, Intrinsics, Motion,
    MotionOptions, RayKind, Request,
};

fn msn(eye: DVec3) -> Camera {
    Camera::msn(eye, 48, 32).unwrap()
}

fn pose(camera: &Camera) -> DMat4 {
    camera.as_pinhole().unwrap().1
}

fn close(a: DVec3, b: DVec3, tolerance: f64) -> bool {
    (a - b).length() < tolerance
}

/// Where a camera's optical axis passes closest to `point`.
fn axis_miss(camera: &Camera, point: DVec3) -> f64 {
    let p = pose(camera);
    let (centre, forward) = (p.w_axis.truncate(), p.z_axis.truncate());
    let offset = point - centre;
    (offset - forward * offset.dot(forward)).length()
}

fn options(frames: usize) -> MotionOptions {
    MotionOptions { frames, centre: DVec3::ZERO, up: DVec3::Z, elevation: None, radius: None, fade: false }
}

#[test]
fn a_pinhole_fitted_to_given_rays_is_the_camera_that_made_them() {
    let camera = msn(DVec3::new(4.0, -3.0, 2.5));
    let (k, p) = camera.as_pinhole().unwrap();
    for kind in [RayKind::UnitDirection, RayKind::UnitDepthPoint] {
        let given = Camera::from_rays(camera.position(), camera.rays_of(kind)).unwrap();
        let (fk, fp) = fit_pinhole(&given, kind).unwrap();
        assert!((fk.fx - k.fx).abs() < 1e-3 && (fk.fy - k.fy).abs() < 1e-3, "{fk:?} vs {k:?}");
        assert_eq!((fk.cx, fk.cy, fk.width, fk.height), (k.cx, k.cy, k.width, k.height));
        assert!(fp.abs_diff_eq(p, 1e-5), "{kind:?}: {fp:?} vs {p:?}");
    }
}

#[test]
fn the_centre_is_where_the_cameras_look_and_up_follows_the_scene() {
    // z-up MultiShapeNet cameras look at the origin.
    let ring: Vec<DMat4> = [DVec3::new(8.0, -2.0, 5.0), DVec3::new(-6.0, 7.0, 4.0), DVec3::new(2.0, 9.0, 6.0)]
        .map(|e| pose(&msn(e)))
        .to_vec();
    assert!(close(scene_centre(&ring).unwrap(), DVec3::ZERO, 1e-9));
    assert_eq!(up_axis(&ring), DVec3::Z);
    // The same ring in a y-up NeRF world (x, y, z) -> (x, z, -y), looking at (1, 2, 3), OpenGL poses.
    let to_y_up = DMat3::from_cols(DVec3::X, -DVec3::Z, DVec3::Y);
    let target = DVec3::new(1.0, 2.0, 3.0);
    let y_up: Vec<DMat4> = [DVec3::new(8.0, -2.0, 5.0), DVec3::new(-6.0, 7.0, 4.0), DVec3::new(2.0, 9.0, 6.0)]
        .map(|e| {
            let eye = target + to_y_up * e;
            let camera = Camera::look_at(eye, target, DVec3::Y, Intrinsics::msn(48, 32)).unwrap();
            let cv = pose(&camera);
            // As a NeRF transforms.json stores it (OpenGL axes), read back with CameraAxes::OpenGl.
            let gl = DMat4::from_cols(cv.x_axis, -cv.y_axis, -cv.z_axis, cv.w_axis);
            pose(&Camera::pinhole(Intrinsics::msn(48, 32), gl, CameraAxes::OpenGl).unwrap())
        })
        .to_vec();
    assert!(close(scene_centre(&y_up).unwrap(), target, 1e-9));
    assert_eq!(up_axis(&y_up), DVec3::Y);
    // An orbit of the y-up scene keeps the height along y.
    let start = (Intrinsics::msn(48, 32), y_up[0]);
    let orbit =
        motion_path(Motion::Orbit, start, &MotionOptions { centre: target, up: DVec3::Y, ..options(8) }).unwrap();
    for camera in &orbit {
        assert!((camera.position().y - y_up[0].w_axis.y).abs() < 1e-9);
        assert!(axis_miss(camera, target) < 1e-9);
    }
    let parallel = [pose(&msn(DVec3::new(5.0, 0.0, 0.0))), pose(&msn(DVec3::new(9.0, 0.0, 0.0)))];
    assert!(scene_centre(&parallel).unwrap_err().to_string().contains("no common look-at point"));
    assert!(scene_centre(&ring[..1]).is_err());
}

#[test]
fn every_motion_preset_moves_as_documented() {
    let start = msn(DVec3::new(6.0, -6.0, 3.0));
    let (k, p) = start.as_pinhole().unwrap();
    let radius = start.position().length();
    let elevation = (3.0 / radius).asin();
    let n = 8;
    let path = |motion, o: MotionOptions| motion_path(motion, (k, p), &o).unwrap();

    let orbit = path(Motion::Orbit, options(n));
    assert_eq!(orbit.len(), n);
    assert!(close(orbit[0].position(), start.position(), 1e-9), "an orbit starts at the start camera");
    for (i, camera) in orbit.iter().enumerate() {
        assert!((camera.position().length() - radius).abs() < 1e-9 && (camera.position().z - 3.0).abs() < 1e-9);
        assert!(axis_miss(camera, DVec3::ZERO) < 1e-9);
        let turned = DMat3::from_rotation_z(std::f64::consts::TAU * i as f64 / n as f64) * start.position();
        assert!(close(camera.position(), turned, 1e-9), "frame {i} is {i}/{n} of a turn");
    }
    let higher = path(Motion::Orbit, MotionOptions { elevation: Some(60.0), radius: Some(5.0), ..options(n) });
    assert!((higher[3].position().z - 5.0 * 60f64.to_radians().sin()).abs() < 1e-9);
    assert!((higher[3].position().length() - 5.0).abs() < 1e-9);

    let spiral = path(Motion::Spiral, options(n));
    let heights: Vec<f64> = spiral.iter().map(|c| (c.position().z / radius).asin()).collect();
    assert!((heights[0] - (elevation - 20f64.to_radians())).abs() < 1e-9);
    assert!((heights[n - 1] - (elevation + 20f64.to_radians())).abs() < 1e-9);
    assert!(heights.windows(2).all(|w| w[1] > w[0]), "the spiral climbs: {heights:?}");

    let zoom = path(Motion::Zoom, options(n));
    let focal = |c: &Camera| c.as_pinhole().unwrap().0.fx;
    assert!(zoom.iter().all(|c| close(c.position(), start.position(), 1e-9)));
    assert!((focal(&zoom[0]) - k.fx).abs() < 1e-9 && (focal(&zoom[n - 1]) - 5.0 * k.fx).abs() < 1e-9);

    let closeup = path(Motion::Closeup, options(n));
    let distances: Vec<f64> = closeup.iter().map(|c| c.position().length()).collect();
    assert!(distances.windows(2).all(|w| w[1] < w[0]), "the closeup moves in: {distances:?}");
    let last = closeup[n - 1].position();
    assert!(close(last, DVec3::new(0.2 * 6.0, -0.2 * 6.0, 0.1 * 3.0), 1e-9), "{last}");

    let eyeroll = path(Motion::Eyeroll, options(n));
    for camera in &eyeroll {
        assert!(close(camera.position(), start.position(), 1e-9));
        // The gaze passes through a point 0.2 radius from the centre, in the centre's level plane.
        let q = pose(camera);
        let (c, f) = (q.w_axis.truncate(), q.z_axis.truncate());
        let hit = c + f * (-c.z / f.z);
        assert!((hit.length() - 0.2 * radius).abs() < 1e-9, "{hit}");
    }

    let faded = path(Motion::Orbit, MotionOptions { fade: true, ..options(n) });
    let step = |cams: &[Camera]| (cams[1].position() - cams[0].position()).length();
    assert!(step(&faded) < step(&orbit) / 2.0, "a fade starts slowly");
}

#[test]
fn interpolation_passes_through_the_keys_smoothly() {
    let keys: Vec<(Intrinsics, DMat4)> =
        [DVec3::new(8.0, 0.0, 4.0), DVec3::new(0.0, 8.0, 4.0), DVec3::new(-8.0, 0.0, 4.0)]
            .map(|e| msn(e).as_pinhole().unwrap())
            .to_vec();
    let frames = interpolate(&keys, 9).unwrap();
    assert_eq!(frames.len(), 9);
    for (key, frame) in [(0, 0), (1, 4), (2, 8)] {
        assert!(pose(&frames[frame]).abs_diff_eq(keys[key].1, 1e-9), "frame {frame} is key {key}");
    }
    // Halfway between two keys: the slerped rotation and a point of the spline between them.
    let middle = pose(&frames[2]);
    let rotation = DMat3::from_mat4(middle);
    assert!((rotation.transpose() * rotation).abs_diff_eq(DMat3::IDENTITY, 1e-9));
    // The keys are one camera turned 90° about z: halfway is turned 45°.
    let halfway = DMat3::from_rotation_z(std::f64::consts::FRAC_PI_4) * DMat3::from_mat4(keys[0].1);
    assert!(rotation.abs_diff_eq(halfway, 1e-9), "{rotation:?} vs {halfway:?}");
    let p = middle.w_axis.truncate();
    assert!(p.x > 0.0 && p.y > 0.0 && (p.z - 4.0).abs() < 1e-9);
    let other = (Intrinsics::msn(64, 48), keys[1].1);
    assert!(interpolate(&[keys[0], other], 4).unwrap_err().to_string().contains("need one size"));
}

#[test]
fn resizing_keeps_the_vertical_field_of_view_and_the_principal_points_place_and_fov_sets_it() {
    let k = Intrinsics::msn(48, 32);
    let big = resized(k, Some((96, 64)), None).unwrap();
    assert_eq!((big.fx, big.cx, big.cy), (2.0 * k.fx, 48.0, 32.0));
    // Off centre, to another aspect: fx and fy scale with the height, cx with the width, cy with the height.
    let off = Intrinsics { width: 80, height: 60, fx: 70.0, fy: 72.0, cx: 30.0, cy: 20.0 };
    let other = resized(off, Some((160, 90)), None).unwrap();
    assert_eq!((other.fx, other.fy, other.cx, other.cy), (105.0, 108.0, 60.0, 30.0));
    let wide = resized(k, None, Some(90.0)).unwrap();
    assert!((wide.fy - 16.0).abs() < 1e-9 && wide.fx == wide.fy);
    assert!(resized(k, None, Some(180.0)).is_err() && resized(k, Some((0, 32)), None).is_err());
}

#[test]
fn a_path_renders_as_each_camera_alone_in_one_plan() {
    let engine = raypatch::Engine::new(Default::default()).unwrap();
    let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k4");
    let model = engine.load(format!("{golden}/model.safetensors")).unwrap();
    let scene =
        model.encode(&raypatch::SceneData::load(format!("{golden}/scene.safetensors")).unwrap().inputs).unwrap();
    let start = msn(DVec3::new(6.0, 4.0, 3.0)).as_pinhole().unwrap();
    let cameras = motion_path(Motion::Orbit, start, &options(5)).unwrap();
    let request = Request::default();
    let frames: Vec<_> = scene.render_path(&cameras, &request, 2).collect::<Result<_, _>>().unwrap();
    assert_eq!(frames.len(), 5);
    assert_eq!(scene.cached_plans(), 1, "batches of 2, the last filled up: one plan");
    for (camera, frame) in cameras.iter().zip(&frames) {
        let alone = scene.render(camera, &request).unwrap();
        let worst = (alone.rgb().unwrap().data().iter().zip(frame.rgb().unwrap().data()))
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-5, "batched and alone differ by {worst}");
    }
    let mut odd = cameras.clone();
    odd.push(Camera::msn(DVec3::new(6.0, 4.0, 3.0), 32, 32).unwrap());
    let results: Vec<_> = scene.render_path(&odd, &request, 3).collect();
    assert!(results[3].as_ref().unwrap_err().to_string().contains("one size"));
    assert_eq!(results.len(), 4, "an error ends the path");
}
