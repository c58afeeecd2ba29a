//! Camera paths for `Scene.render_path`: motion presets, interpolation, the scene's centre and up axis, and
//! camera path files, as pinhole cameras `(row-major 4x4 camera-to-world pose with OpenCV axes, (fx, fy, cx,
//! cy, width, height))`.

use std::path::PathBuf;

use glam::{DMat4, DVec3};
use pyo3::prelude::*;
use raypatch::{Camera, CameraAxes, Intrinsics, Motion, MotionOptions};

use crate::{input_error, to_py};

/// A pinhole camera across the binding: the pose row-major with OpenCV axes, and (fx, fy, cx, cy, w, h).
pub type Pinhole = ([f64; 16], (f64, f64, f64, f64, usize, usize));

pub fn to_tuple((k, pose): (Intrinsics, DMat4)) -> Pinhole {
    (pose.transpose().to_cols_array(), (k.fx, k.fy, k.cx, k.cy, k.width, k.height))
}

fn from_tuple((pose, (fx, fy, cx, cy, width, height)): Pinhole) -> (Intrinsics, DMat4) {
    (Intrinsics { width, height, fx, fy, cx, cy }, DMat4::from_cols_array(&pose).transpose())
}

/// A pinhole tuple as a camera.
pub fn camera_of(camera: Pinhole) -> PyResult<Camera> {
    let (k, pose) = from_tuple(camera);
    Camera::pinhole(k, pose, CameraAxes::OpenCv).map_err(to_py)
}

fn tuples(cameras: Vec<Camera>) -> Vec<Pinhole> {
    cameras.iter().map(|c| to_tuple(c.as_pinhole().expect("motions and interpolations make pinhole cameras"))).collect()
}

fn poses(poses: Vec<[f64; 16]>) -> Vec<DMat4> {
    poses.iter().map(|p| DMat4::from_cols_array(p).transpose()).collect()
}

/// The cameras of a motion preset from `start` (see raypatch::motion_path).
#[pyfunction]
#[pyo3(signature = (motion, start, frames, centre, up, elevation=None, radius=None, fade=false))]
#[allow(clippy::too_many_arguments)] // the preset's options, each a keyword in Python
pub fn motion_cameras(
    motion: &str,
    start: Pinhole,
    frames: usize,
    centre: [f64; 3],
    up: [f64; 3],
    elevation: Option<f64>,
    radius: Option<f64>,
    fade: bool,
) -> PyResult<Vec<Pinhole>> {
    let names: Vec<&str> = Motion::ALL.iter().map(|m| m.name()).collect();
    let motion = Motion::from_name(motion)
        .ok_or_else(|| input_error(format!("motion {motion:?}: expected one of {}", names.join(", "))))?;
    if frames == 0 || frames > raypatch::MAX_PATH_FRAMES {
        return Err(input_error(format!("frames {frames}: expected 1 to {}", raypatch::MAX_PATH_FRAMES)));
    }
    if let Some(e) = elevation.filter(|e| !(-90.0..=90.0).contains(e)) {
        return Err(input_error(format!("elevation {e}: expected degrees from -90 to 90")));
    }
    let (centre, up) = (DVec3::from_array(centre), DVec3::from_array(up));
    if !centre.is_finite() || !up.is_finite() || up.length() < 1e-9 {
        return Err(input_error(format!("centre {centre} and up {up}: expected finite points, a non-zero up")));
    }
    let options = MotionOptions { frames, centre, up, elevation, radius, fade };
    Ok(tuples(raypatch::motion_path(motion, from_tuple(start), &options).map_err(to_py)?))
}

/// `frames` cameras along a smooth path through the key cameras (see raypatch::interpolate).
#[pyfunction]
pub fn interpolate_cameras(keys: Vec<Pinhole>, frames: usize) -> PyResult<Vec<Pinhole>> {
    if frames == 0 || frames > raypatch::MAX_PATH_FRAMES {
        return Err(input_error(format!("frames {frames}: expected 1 to {}", raypatch::MAX_PATH_FRAMES)));
    }
    let keys: Vec<(Intrinsics, DMat4)> = keys.into_iter().map(from_tuple).collect();
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
