//! Camera paths for `Scene.render_path`: motion presets, interpolation, the scene's centre and up axis, and
//! camera path files, as pinhole cameras `(row-major 4x4 camera-to-world pose with OpenCV axes, (fx, fy, cx,
//! cy, width, height))`.

use std::path::PathBuf;

use glam::{DMat4, DVec3};
use pyo3::prelude::*;
use raypatch::raypatch_model::error::Quoted;
use raypatch::{Camera, CameraAxes, Intrinsics, Motion, MotionOptions};

use crate::{input_error, to_py, unsigned};

/// A pinhole camera's (fx, fy, cx, cy, width, height) across the binding (signed: see [`unsigned`]).
pub type PinholeK = (f64, f64, f64, f64, i64, i64);
/// A pinhole camera across the binding: the pose row-major with OpenCV axes, and its [`PinholeK`].
pub type Pinhole = ([f64; 16], PinholeK);

pub fn to_tuple((k, pose): (Intrinsics, DMat4)) -> Pinhole {
    // Sizes of cameras the engine made: within MAX_IMAGE_SIDE, far from i64's limit.
    (pose.transpose().to_cols_array(), (k.fx, k.fy, k.cx, k.cy, k.width as i64, k.height as i64))
}

/// The intrinsics of a [`PinholeK`].
pub fn intrinsics_of((fx, fy, cx, cy, width, height): PinholeK) -> PyResult<Intrinsics> {
    Ok(Intrinsics { width: unsigned("width", width)?, height: unsigned("height", height)?, fx, fy, cx, cy })
}

fn from_tuple((pose, k): Pinhole) -> PyResult<(Intrinsics, DMat4)> {
    Ok((intrinsics_of(k)?, DMat4::from_cols_array(&pose).transpose()))
}

/// A pinhole tuple as a camera.
pub fn camera_of(camera: Pinhole) -> PyResult<Camera> {
    let (k, pose) = from_tuple(camera)?;
    Camera::pinhole(k, pose, CameraAxes::OpenCv).map_err(to_py)
}

fn tuples(cameras: Vec<Camera>) -> Vec<Pinhole> {
    cameras.iter().map(|c| to_tuple(c.as_pinhole().expect("motions and interpolations make pinhole cameras"))).collect()
}

fn poses(poses: Vec<[f64; 16]>) -> Vec<DMat4> {
    poses.iter().map(|p| DMat4::from_cols_array(p).transpose()).collect()
}

/// A path's frame count: 1 to MAX_PATH_FRAMES.
fn frame_count(frames: i64) -> PyResult<usize> {
    let most = raypatch::MAX_PATH_FRAMES;
    match unsigned("frames", frames)? {
        n if n == 0 || n > most => Err(input_error(format!("frames {n}: expected 1 to {most}"))),
        n => Ok(n),
    }
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
    let frames = frame_count(frames)?;
    if let Some(e) = elevation.filter(|e| !(-90.0..=90.0).contains(e)) {
        return Err(input_error(format!("elevation {e}: expected degrees from -90 to 90")));
    }
    let (centre, up) = (DVec3::from_array(centre), DVec3::from_array(up));
    if !centre.is_finite() || !up.is_finite() || up.length() < 1e-9 {
        return Err(input_error(format!("centre {centre} and up {up}: expected finite points, a non-zero up")));
    }
    let options = MotionOptions { frames, centre, up, elevation, radius, fade };
    Ok(tuples(raypatch::motion_path(motion, from_tuple(start)?, &options).map_err(to_py)?))
}

/// `frames` cameras along a smooth path through the key cameras (see raypatch::interpolate).
#[pyfunction]
pub fn interpolate_cameras(keys: Vec<Pinhole>, frames: i64) -> PyResult<Vec<Pinhole>> {
    let frames = frame_count(frames)?;
    let keys: Vec<(Intrinsics, DMat4)> = keys.into_iter().map(from_tuple).collect::<PyResult<_>>()?;
    Ok(tuples(raypatch::interpolate(&keys, frames).map_err(to_py)?))
}

/// The point nearest to the cameras' optical axes (OpenCV poses).
#[pyfunction]
pub fn scene_centre(camera_poses: Vec<[f64; 16]>) -> PyResult<[f64; 3]> {
    Ok(raypatch::scene_centre(&poses(camera_poses)).map_err(to_py)?.to_array())
}

/// The world axis nearest to the cameras' image-up directions (OpenCV poses).
#[pyfunction]
pub fn up_axis(camera_poses: Vec<[f64; 16]>) -> [f64; 3] {
    raypatch::up_axis(&poses(camera_poses)).to_array()
}

/// The cameras of a camera path file (nerfstudio's camera_path.json or raypatch's form) and its fps.
#[pyfunction]
pub fn camera_path_cameras(py: Python<'_>, path: PathBuf) -> PyResult<(Vec<Pinhole>, Option<f64>)> {
    let path = py.detach(|| raypatch::load_camera_path(&path)).map_err(to_py)?;
    Ok((tuples(path.cameras), path.fps))
}
