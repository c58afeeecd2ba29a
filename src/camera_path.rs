//! Camera paths: the cameras of a fly-through, read from nerfstudio's `camera_path.json` (what its viewer's
//! render panel exports) or from raypatch's own form of the same things.
//!
//! nerfstudio (`ns-render camera-path`): `render_width`, `render_height`, `camera_type` (only `perspective`,
//! the default, is rendered here), optional `fps`, and `camera_path`: per frame `camera_to_world`, 16 numbers
//! of a row-major 4x4 matrix with OpenGL axes (x right, y up, looking along −z), and `fov`, the vertical field
//! of view in degrees (focal length `(height / 2) / tan(fov / 2)`, principal point at the image centre). Other
//! keys (`keyframes`, `seconds`, `smoothness_value`, `aspect`, `render_time`, `crop`) are not used.
//!
//! raypatch's form: `width`, `height`, optional `fps` and `convention` (`"opengl"`, the default, or `"opencv"`:
//! x right, y down, looking along +z), and `frames`: per frame `camera_to_world` (a 4x4 matrix as 4 rows, or 16
//! numbers row-major) and either `fov` (vertical, degrees) or `fl_x`, `fl_y` and optionally `cx`, `cy` (pixels),
//! each of which may instead be given once at the top level for every frame.

use std::path::Path;

use raypatch_model::error::Quoted;
use serde_json::Value;

use crate::camera::{Camera, CameraAxes, Intrinsics};
use crate::dataset::{json_pose, number, pixels};
use crate::error::{Error, Result};
use crate::input::{FieldOfView, MAX_PATH_FRAMES};

/// The cameras of a camera path file, in order, and its frame rate when it gives one.
#[derive(Clone, Debug)]
pub struct CameraPath {
    pub cameras: Vec<Camera>,
    pub fps: Option<f64>,
}

/// Reads a camera path file: nerfstudio's `camera_path.json` (it has `camera_path`) or raypatch's form (it has
/// `frames`); see the module documentation for the keys. Every error names the file, and the frame and key.
///
/// ```
/// let path = std::env::temp_dir().join("raypatch-doc-camera-path.json");
/// std::fs::write(&path, r#"{"render_width": 80, "render_height": 60, "camera_type": "perspective",
///     "camera_path": [{"camera_to_world": [1,0,0,0, 0,0,-1,-6, 0,1,0,1, 0,0,0,1], "fov": 40}]}"#).unwrap();
/// let cameras = raypatch::load_camera_path(&path)?.cameras;
/// assert_eq!((cameras.len(), cameras[0].width(), cameras[0].height()), (1, 80, 60));
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn load_camera_path(path: impl AsRef<Path>) -> Result<CameraPath> {
    let path = path.as_ref();
    let err = |reason: String| Error::Cameras { path: path.display().to_string(), reason };
    let text = crate::dataset::read_json_text(path)?;
    let root: Value = serde_json::from_str(&text).map_err(|e| err(format!("not valid JSON: {e}")))?;
    if !root.is_object() {
        return Err(err("expected a JSON object with `camera_path` (nerfstudio) or `frames`".into()));
    }
    let nerfstudio = root.get("camera_path").is_some();
    let (list_key, width_key, height_key) =
        if nerfstudio { ("camera_path", "render_width", "render_height") } else { ("frames", "width", "height") };
    if nerfstudio {
        match root.get("camera_type") {
            None | Some(Value::Null) => {}
            Some(Value::String(t)) if t == "perspective" => {}
            Some(other) => {
                return Err(err(format!(
                "`camera_type` is {other}: only \"perspective\" cameras are rendered (not fisheye, equirectangular, \
                     omnidirectional or vr180)"
            )))
            }
        }
    }
    let size = |key: &str| match number(&Value::Null, &root, key)? {
        Some(v) => pixels(key, v),
        None => Err(format!("no `{key}` (the image size in pixels)")),
    };
    let (width, height) = (size(width_key).map_err(err)?, size(height_key).map_err(err)?);
    crate::image::check_image_size(width, height).map_err(|e| err(e.to_string()))?;
    let fps = match root.get("fps") {
        None | Some(Value::Null) => None,
        Some(v) => match v.as_f64() {
            Some(f) if f.is_finite() && f > 0.0 => Some(f),
            _ => return Err(err(format!("`fps` is {}, expected a positive number", Quoted(v)))),
        },
    };
    let axes = match root.get("convention") {
        _ if nerfstudio => CameraAxes::OpenGl,
        None | Some(Value::Null) => CameraAxes::OpenGl,
        Some(Value::String(name)) => name.parse().map_err(|e| err(format!("`convention`: {}", reason(e))))?,
        Some(other) => {
            return Err(err(format!("`convention` is {}, expected \"opengl\" or \"opencv\"", Quoted(other))))
        }
    };
    let frames = root
        .get(list_key)
        .and_then(Value::as_array)
        .ok_or_else(|| err(format!("`{list_key}` is not a list of cameras")))?;
    if frames.is_empty() || frames.len() > MAX_PATH_FRAMES {
        return Err(err(format!("`{list_key}` holds {} cameras, expected 1 to {MAX_PATH_FRAMES}", frames.len())));
    }
    let camera = |frame: &Value| -> Result<Camera> {
        let intrinsics = intrinsics(&root, frame, width, height, nerfstudio).map_err(Error::Camera)?;
        Camera::pinhole(intrinsics, json_pose(frame, "camera_to_world").map_err(Error::Camera)?, axes)
    };
    let cameras = (frames.iter().enumerate())
        .map(|(i, frame)| camera(frame).map_err(|e| err(format!("`{list_key}` {i}: {}", reason(e)))))
        .collect::<Result<Vec<_>>>()?;
    Ok(CameraPath { cameras, fps })
}

/// What is wrong with a frame's camera, as its line in the file's error says it.
fn reason(e: Error) -> String {
    match e {
        Error::Camera(reason) => reason,
        other => other.to_string(),
    }
}

/// A frame's intrinsics: `fov` (vertical, degrees), or `fl_x`/`fl_y`/`cx`/`cy`, from the frame or else the
/// top level (raypatch's form; nerfstudio's frames have `fov`).
fn intrinsics(
    root: &Value,
    frame: &Value,
    width: usize,
    height: usize,
    nerfstudio: bool,
) -> std::result::Result<Intrinsics, String> {
    // nerfstudio's keys are per frame only.
    let shared = if nerfstudio { &Value::Null } else { root };
    let get = |key: &str| number(shared, frame, key);
    let (cx, cy) = (get("cx")?.unwrap_or(width as f64 / 2.0), get("cy")?.unwrap_or(height as f64 / 2.0));
    if let Some(fov) = get("fov")? {
        let focal = FieldOfView::degrees(fov).map_err(|e| format!("`fov` is {e}"))?.focal(height);
        return Ok(Intrinsics { width, height, fx: focal, fy: focal, cx, cy });
    }
    match (get("fl_x")?, get("fl_y")?) {
        (Some(fx), fy) => Ok(Intrinsics { width, height, fx, fy: fy.unwrap_or(fx), cx, cy }),
        _ => Err("no `fov` (vertical, degrees) or `fl_x` (pixels)".into()),
    }
}
