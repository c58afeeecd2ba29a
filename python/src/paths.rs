//! Cameras across the binding, as pinhole cameras `(row-major 4x4 camera-to-world pose with OpenCV axes, (fx,
//! fy, cx, cy, width, height))`: poses given in either convention, a camera resized, and the camera paths of
//! `Scene.render_path` (motion presets, interpolation, the scene's centre and up axis, camera path files).
//! Poses, conventions, sizes and frame counts are checked by `raypatch::input`.

use std::path::PathBuf;

use glam::{DMat4, DVec3};
use pyo3::prelude::*;
use raypatch::raypatch_model::error::Quoted;
use raypatch::{input, Camera, CameraAxes, Intrinsics, Motion, MotionOptions};

use crate::convert::{f64s, input_error, to_py, unsigned};

/// A pinhole camera's (fx, fy, cx, cy, width, height) across the binding (signed: see [`unsigned`]).
pub type PinholeK = (f64, f64, f64, f64, i64, i64);
/// A pinhole camera across the binding: the pose row-major with OpenCV axes, and its [`PinholeK`].
pub type Pinhole = ([f64; 16], PinholeK);

pub fn to_tuple((k, pose): (Intrinsics, DMat4)) -> Pinhole {
    (input::pose_numbers(pose), k_tuple(k))
}

fn k_tuple(k: Intrinsics) -> PinholeK {
    // Sizes of cameras the engine made: within MAX_IMAGE_SIDE, far from i64's limit.
    (k.fx, k.fy, k.cx, k.cy, k.width as i64, k.height as i64)
}

/// The intrinsics of a [`PinholeK`].
fn intrinsics_of((fx, fy, cx, cy, width, height): PinholeK) -> PyResult<Intrinsics> {
    Ok(Intrinsics { width: unsigned("width", width)?, height: unsigned("height", height)?, fx, fy, cx, cy })
}

fn from_tuple((pose, k): Pinhole) -> PyResult<(Intrinsics, DMat4)> {
    Ok((intrinsics_of(k)?, input::pose_from_numbers(&pose).map_err(to_py)?))
}

/// `count` row-major 4x4 camera-to-world poses (little-endian float64 bytes) whose camera frames have the axes
/// `convention` names, each checked to be rigid, with OpenCV axes (the binding's form); errors name `name` and
/// the pose.
#[pyfunction]
pub fn opencv_poses(name: &str, poses: &[u8], count: i64, convention: &str) -> PyResult<Vec<[f64; 16]>> {
    let axes: CameraAxes = convention.parse().map_err(to_py)?;
    let numbers = f64s(name, poses, unsigned(name, count)?.saturating_mul(16))?;
    (numbers.chunks_exact(16).enumerate())
        .map(|(i, pose)| {
            let pose = input::pose_from_numbers(pose).map_err(|e| input_error(format!("{name} {i}: {e}")))?;
            Ok(input::pose_numbers(axes.to_opencv(pose)))
        })
        .collect()
}

/// A camera's intrinsics at another image size (`raypatch::input::resized_to`: the vertical field of view and
/// the principal point's relative position kept).
#[pyfunction]
pub fn resized_camera(k: PinholeK, width: i64, height: i64) -> PyResult<PinholeK> {
    let (width, height) = (unsigned("width", width)?, unsigned("height", height)?);
    Ok(k_tuple(input::resized_to(intrinsics_of(k)?, width, height).map_err(to_py)?))
}

/// A pinhole tuple as a camera.
pub fn camera_of(camera: Pinhole) -> PyResult<Camera> {
    let (k, pose) = from_tuple(camera)?;
    Camera::pinhole(k, pose, CameraAxes::OpenCv).map_err(to_py)
}

fn tuples(cameras: Vec<Camera>) -> Vec<Pinhole> {
    cameras.iter().map(|c| to_tuple(c.as_pinhole().expect("motions and interpolations make pinhole cameras"))).collect()
}

fn poses(poses: Vec<[f64; 16]>) -> PyResult<Vec<DMat4>> {
    poses.iter().map(|p| input::pose_from_numbers(p).map_err(to_py)).collect()
}

/// The cameras of a motion preset from `start` (see raypatch::motion_path).
#[pyfunction]
#[pyo3(signature = (motion, start, frames, centre, up, elevation=None, radius=None, fade=false))]
#[allow(clippy::too_many_arguments)] // the preset's options, each a keyword in Python
pub fn motion_cameras(
    motion: &str,
    start: Pinhole,
    frames: i64,
    centre: [f64; 3],
    up: [f64; 3],
    elevation: Option<f64>,
    radius: Option<f64>,
    fade: bool,
) -> PyResult<Vec<Pinhole>> {
    let names: Vec<&str> = Motion::ALL.iter().map(|m| m.name()).collect();
    let motion = Motion::from_name(motion)
        .ok_or_else(|| input_error(format!("motion {:?}: expected one of {}", Quoted(motion), names.join(", "))))?;
    let frames = unsigned("frames", frames)?;
    let (centre, up) = (DVec3::from_array(centre), DVec3::from_array(up));
    let options = MotionOptions { frames, centre, up, elevation, radius, fade };
    Ok(tuples(raypatch::motion_path(motion, from_tuple(start)?, &options).map_err(to_py)?))
}

/// `frames` cameras along a smooth path through the key cameras (see raypatch::interpolate).
#[pyfunction]
pub fn interpolate_cameras(keys: Vec<Pinhole>, frames: i64) -> PyResult<Vec<Pinhole>> {
    let frames = unsigned("frames", frames)?;
    let keys: Vec<(Intrinsics, DMat4)> = keys.into_iter().map(from_tuple).collect::<PyResult<_>>()?;
    Ok(tuples(raypatch::interpolate(&keys, frames).map_err(to_py)?))
}

/// The point nearest to the cameras' optical axes (OpenCV poses).
#[pyfunction]
pub fn scene_centre(camera_poses: Vec<[f64; 16]>) -> PyResult<[f64; 3]> {
    Ok(raypatch::scene_centre(&poses(camera_poses)?).map_err(to_py)?.to_array())
}

/// The world axis nearest to the cameras' image-up directions (OpenCV poses).
#[pyfunction]
pub fn up_axis(camera_poses: Vec<[f64; 16]>) -> PyResult<[f64; 3]> {
    Ok(raypatch::up_axis(&poses(camera_poses)?).to_array())
}

/// The cameras of a camera path file (nerfstudio's camera_path.json or raypatch's form) and its fps.
#[pyfunction]
pub fn camera_path_cameras(py: Python<'_>, path: PathBuf) -> PyResult<(Vec<Pinhole>, Option<f64>)> {
    let path = py.detach(|| raypatch::load_camera_path(&path)).map_err(to_py)?;
    Ok((tuples(path.cameras), path.fps))
}
