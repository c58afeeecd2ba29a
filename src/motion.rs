//! Camera motions for videos: presets about a scene's centre (orbit, spiral, zoom, closeup, eyeroll, after
//! stelzner/srt's `render.py --motion`), smooth interpolation between key cameras (Catmull-Rom positions, slerped
//! rotations). A camera's size or field of view is changed by `crate::input::resized`.
//!
//! Every camera here is a pinhole camera. Cameras given as rays (scene files store rays) are first fitted with
//! one ([`fit_pinhole`]): a centred principal point and the pose and focal lengths their corner rays give,
//! exact for the MultiShapeNet cameras.

use glam::{DMat3, DMat4, DQuat, DVec3};

use crate::camera::{Camera, CameraAxes, Intrinsics, RayKind};
use crate::error::{Error, Result};

/// The motion presets of [`motion_path`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    /// One turn about the up axis through the centre, at a fixed elevation and radius, looking at the centre.
    Orbit,
    /// Two turns about the up axis while the elevation climbs from 20° below to 20° above the start's.
    Spiral,
    /// The start camera stays; its focal length grows to 5 times (a narrowing field of view).
    Zoom,
    /// The camera moves in towards the centre and down, its gaze panning past the centre (srt's `closeup`).
    Closeup,
    /// The camera stays; its gaze circles the centre at a fifth of its distance (srt's `eyeroll`).
    Eyeroll,
}

impl Motion {
    pub const ALL: [Motion; 5] = [Motion::Orbit, Motion::Spiral, Motion::Zoom, Motion::Closeup, Motion::Eyeroll];

    pub fn name(self) -> &'static str {
        match self {
            Motion::Orbit => "orbit",
            Motion::Spiral => "spiral",
            Motion::Zoom => "zoom",
            Motion::Closeup => "closeup",
            Motion::Eyeroll => "eyeroll",
        }
    }

    pub fn from_name(name: &str) -> Option<Motion> {
        Motion::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Whether the motion ends where it starts (its frames are `i / n` of the way; the others reach the end).
    fn loops(self) -> bool {
        matches!(self, Motion::Orbit | Motion::Eyeroll)
    }
}

/// Where a motion happens: the centre it looks at, the world's up axis, and the start camera's elevation and
/// distance from the centre (each `None` keeps the start camera's own).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionOptions {
    pub frames: usize,
    pub centre: DVec3,
    /// Unit vector: the world's up (+z for MultiShapeNet, +y for NeRF's y-up scenes).
    pub up: DVec3,
    /// Degrees above the plane through the centre perpendicular to `up`.
    pub elevation: Option<f64>,
    /// Distance from the centre.
    pub radius: Option<f64>,
    /// Ease in and out (srt's `--fade`): the motion starts and stops smoothly.
    pub fade: bool,
}

impl MotionOptions {
    /// `frames` frames about the scene whose cameras have `poses` ([`fitted_poses`]): looking at `centre`, by
    /// default the point nearest their optical axes ([`scene_centre`], an error where there is none), `up` by
    /// default the axis nearest theirs ([`up_axis`]); the start camera's own elevation and radius, no fade.
    pub fn about(poses: &[DMat4], frames: usize, centre: Option<DVec3>, up: Option<DVec3>) -> Result<MotionOptions> {
        let centre = match centre {
            Some(centre) => centre,
            None => scene_centre(poses)?,
        };
        let up = up.unwrap_or_else(|| up_axis(poses));
        Ok(MotionOptions { frames, centre, up, elevation: None, radius: None, fade: false })
    }
}

/// A camera's pinhole intrinsics and camera-to-world pose (OpenCV axes): its own for a pinhole camera, fitted
/// from its rays (of `kind`) for a camera given as rays: a centred principal point, the forward axis along the
/// sum of the corner rays, right from the left corners to the right ones, and each focal length from the
/// corner rays' angles. Exact for any centred pinhole camera with square or non-square pixels.
pub fn fit_pinhole(camera: &Camera, kind: RayKind) -> Result<(Intrinsics, DMat4)> {
    if let Some(pinhole) = camera.as_pinhole() {
        return Ok(pinhole);
    }
    let grid = camera.given_rays().expect("a camera is a pinhole or given as rays");
    let (gw, gh) = (grid.width, grid.height);
    let direction = |i: usize, j: usize| {
        let ray = grid.rays[i * gw + j].as_dvec3();
        match kind {
            RayKind::UnitDirection => ray.normalize(),
            RayKind::UnitDepthPoint => (ray - camera.position()).normalize(),
        }
    };
    let [tl, tr, bl, br] = [direction(0, 0), direction(0, gw - 1), direction(gh - 1, 0), direction(gh - 1, gw - 1)];
    let unfit = || Error::Camera(format!("cannot fit a pinhole camera to the {gw}x{gh} rays: their corners coincide"));
    let forward = (tl + tr + bl + br).try_normalize().ok_or_else(unfit)?;
    let across = tr + br - tl - bl;
    let right = (across - forward * across.dot(forward)).try_normalize().ok_or_else(unfit)?;
    let down = forward.cross(right);
    let (width, height, per_ray) = (camera.width() as f64, camera.height() as f64, camera.pixels_per_ray() as f64);
    // A corner ray's pixel centre lies (pixels - per_ray) / 2 from the image centre along each axis.
    let focal = |axis: DVec3, pixels: f64| {
        let offset = (pixels - per_ray) / 2.0;
        let tangents: Vec<f64> = [tl, tr, bl, br].iter().map(|d| d.dot(axis).abs() / d.dot(forward)).collect();
        let tangent = tangents.iter().sum::<f64>() / 4.0;
        (offset > 0.0 && tangent > 1e-12).then(|| offset / tangent)
    };
    let (fx, fy) = match (focal(right, width), focal(down, height)) {
        (Some(fx), Some(fy)) => (fx, fy),
        (Some(f), None) | (None, Some(f)) => (f, f),
        (None, None) => return Err(unfit()),
    };
    let intrinsics =
        Intrinsics { width: camera.width(), height: camera.height(), fx, fy, cx: width / 2.0, cy: height / 2.0 };
    let pose =
        DMat4::from_cols(right.extend(0.0), down.extend(0.0), forward.extend(0.0), camera.position().extend(1.0));
    Ok((intrinsics, pose))
}

/// The camera-to-world poses (OpenCV axes) of `cameras`, each fitted with a pinhole camera ([`fit_pinhole`]):
/// what [`scene_centre`], [`up_axis`] and [`MotionOptions::about`] take.
pub fn fitted_poses<'a>(cameras: impl IntoIterator<Item = &'a Camera>, kind: RayKind) -> Result<Vec<DMat4>> {
    cameras.into_iter().map(|camera| fit_pinhole(camera, kind).map(|(_, pose)| pose)).collect()
}

/// The point nearest to every camera's optical axis (least squares): where a ring of cameras looks. An error
/// when fewer than two cameras with axes that are not parallel are given.
pub fn scene_centre(poses: &[DMat4]) -> Result<DVec3> {
    let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
    for pose in poses {
        let axis = pose.z_axis.truncate().normalize();
        // Projection onto the plane perpendicular to the axis: the distance to the axis is |P (x - c)|.
        let p = DMat3::IDENTITY - DMat3::from_cols(axis * axis.x, axis * axis.y, axis * axis.z);
        a += p;
        b += p * pose.w_axis.truncate();
    }
    let scale = a.to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if poses.len() < 2 || a.determinant().abs() <= 1e-9 * scale.powi(3) {
        return Err(Error::Camera(format!(
            "the scene's {} camera(s) have no common look-at point (fewer than two cameras, or parallel optical \
             axes): give the centre",
            poses.len()
        )));
    }
    Ok(a.inverse() * b)
}

/// The world axis (±x, ±y or ±z) nearest to the mean of the cameras' image-up directions: +z for
/// MultiShapeNet's z-up scenes, +y for NeRF's y-up scenes.
pub fn up_axis(poses: &[DMat4]) -> DVec3 {
    let mean: DVec3 = poses.iter().map(|p| -p.y_axis.truncate()).sum();
    let axes = [DVec3::X, DVec3::Y, DVec3::Z, -DVec3::X, -DVec3::Y, -DVec3::Z];
    axes.into_iter().max_by(|a, b| a.dot(mean).total_cmp(&b.dot(mean))).expect("six axes")
}

/// srt's `apply_fade`: constant acceleration over the first and last fifth, constant speed between.
fn fade(t: f64) -> f64 {
    const T_FADE: f64 = 0.2;
    let v_max = 1.0 / (1.0 - T_FADE);
    let acc = v_max / T_FADE;
    if t <= T_FADE {
        0.5 * acc * t * t
    } else if t <= 1.0 - T_FADE {
        0.5 * acc * T_FADE * T_FADE + v_max * (t - T_FADE)
    } else {
        1.0 - 0.5 * acc * (t - 1.0) * (t - 1.0)
    }
}

/// The cameras of a motion preset, starting from `start` (intrinsics and camera-to-world pose, OpenCV axes):
/// `options.frames` cameras with `start`'s intrinsics. The start camera is first placed at the options'
/// elevation and radius (its own by default), at its own azimuth, looking at the centre.
pub fn motion_path(motion: Motion, start: (Intrinsics, DMat4), options: &MotionOptions) -> Result<Vec<Camera>> {
    let n = crate::input::check_frames(options.frames)?;
    if let Some(e) = options.elevation.filter(|e| !(-90.0..=90.0).contains(e)) {
        return Err(Error::Camera(format!("elevation {e}: expected degrees from -90 to 90")));
    }
    let (intrinsics, pose) = start;
    if !options.centre.is_finite() || !options.up.is_finite() || options.up.length() < 1e-9 {
        return Err(Error::Camera(format!(
            "centre {} and up {}: expected finite points, a non-zero up",
            options.centre, options.up
        )));
    }
    let (centre, up) = (options.centre, options.up.normalize());
    let offset = pose.w_axis.truncate() - centre;
    let level = offset - up * offset.dot(up);
    let a1 = level.try_normalize().unwrap_or_else(|| up.any_orthonormal_vector());
    let a2 = up.cross(a1);
    let radius = options.radius.unwrap_or(offset.length());
    let elevation = options.elevation.map_or_else(|| offset.dot(up).atan2(level.length()), f64::to_radians);
    if !(radius.is_finite() && radius > 0.0) {
        return Err(Error::Camera(format!("radius {radius}: expected a positive distance from the centre")));
    }
    let place = |azimuth: f64, elevation: f64, r: f64| {
        centre + r * (elevation.cos() * (azimuth.cos() * a1 + azimuth.sin() * a2) + elevation.sin() * up)
    };
    let look = |eye: DVec3, target: DVec3, k: Intrinsics| Camera::look_at(eye, target, up, k);
    let eye = place(0.0, elevation, radius);
    let tau = std::f64::consts::TAU;
    (0..n)
        .map(|i| {
            let t = match (motion.loops(), n) {
                (_, 1) => 0.0,
                (true, _) => i as f64 / n as f64,
                (false, _) => i as f64 / (n - 1) as f64,
            };
            let t = if options.fade { fade(t) } else { t };
            match motion {
                Motion::Orbit => look(place(tau * t, elevation, radius), centre, intrinsics),
                Motion::Spiral => {
                    let climb = (elevation + (40.0 * t - 20.0).to_radians()).clamp(-1.48, 1.48);
                    look(place(2.0 * tau * t, climb, radius), centre, intrinsics)
                }
                Motion::Zoom => {
                    let zoom = 1.0 + 4.0 * t;
                    look(eye, centre, Intrinsics { fx: intrinsics.fx * zoom, fy: intrinsics.fy * zoom, ..intrinsics })
                }
                Motion::Closeup => {
                    // srt's get_camera_closeup: the eye moves in to a fifth of its level distance and down to a
                    // tenth of its height (eased out), the gaze from the centre to twice the eye's level
                    // distance past it.
                    let (level, height) = (level_of(eye - centre, up), (eye - centre).dot(up));
                    let ease = -0.5 * t * t + 1.5 * t;
                    let at = centre + level * (1.0 - 0.8 * t) + up * height * (1.0 - 0.9 * ease);
                    look(at, centre - 2.0 * t * level, intrinsics)
                }
                Motion::Eyeroll => {
                    let theta = -tau * t;
                    let target = centre + 0.2 * radius * (theta.cos() * a1 + theta.sin() * a2);
                    look(eye, target, intrinsics)
                }
            }
        })
        .collect()
}

/// `v` without its component along `up`.
fn level_of(v: DVec3, up: DVec3) -> DVec3 {
    v - up * v.dot(up)
}

/// `frames` cameras along a smooth path through the key cameras (intrinsics and camera-to-world pose, OpenCV
/// axes), from the first to the last: positions on a Catmull-Rom spline through the keys' centres, rotations
/// slerped between neighbouring keys, focal lengths and principal points linear. Every key must have the
/// same image size.
pub fn interpolate(keys: &[(Intrinsics, DMat4)], frames: usize) -> Result<Vec<Camera>> {
    let frames = crate::input::check_frames(frames)?;
    let Some(&(first, _)) = keys.first() else {
        return Err(Error::Camera("no key camera to interpolate between".into()));
    };
    if let Some((i, (k, _))) =
        keys.iter().enumerate().find(|(_, (k, _))| (k.width, k.height) != (first.width, first.height))
    {
        return Err(Error::Camera(format!(
            "key camera {i} is {}x{}, key camera 0 is {}x{}: interpolated cameras need one size (give --size)",
            k.width, k.height, first.width, first.height
        )));
    }
    let positions: Vec<DVec3> = keys.iter().map(|(_, p)| p.w_axis.truncate()).collect();
    let rotations: Vec<DQuat> = keys.iter().map(|(_, p)| DQuat::from_mat4(p).normalize()).collect();
    let last = keys.len() - 1;
    (0..frames)
        .map(|f| {
            let s = if frames == 1 { 0.0 } else { f as f64 * last as f64 / (frames - 1) as f64 };
            let i = (s.floor() as usize).min(last.saturating_sub(1));
            let t = s - i as f64;
            let j = (i + 1).min(last);
            let at = |n: isize| positions[n.clamp(0, last as isize) as usize];
            let (p0, p1, p2, p3) = (at(i as isize - 1), at(i as isize), at(j as isize), at(j as isize + 1));
            // Uniform Catmull-Rom: passes through every key, tangents from the neighbours.
            let position = 0.5
                * (2.0 * p1
                    + (p2 - p0) * t
                    + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t * t
                    + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t * t * t);
            let rotation = rotations[i].slerp(rotations[j], t);
            let (a, b) = (keys[i].0, keys[j].0);
            let lerp = |x: f64, y: f64| x + (y - x) * t;
            let intrinsics = Intrinsics {
                fx: lerp(a.fx, b.fx),
                fy: lerp(a.fy, b.fy),
                cx: lerp(a.cx, b.cx),
                cy: lerp(a.cy, b.cy),
                ..a
            };
            Camera::pinhole(intrinsics, DMat4::from_rotation_translation(rotation, position), CameraAxes::OpenCv)
        })
        .collect()
}
