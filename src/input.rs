//! Camera input, once for every surface: what the CLI's flags, the viewer's query strings, Python's arrays and
//! a browser's JSON turn their own formats into. A pose from 16 numbers or 4 rows (finite and rigid), the axis
//! convention by name and its flip, a field of view (in (0, 180) degrees), the one policy for resizing a camera,
//! the image sizes a model's patch size allows, and the most frames a sequence may have. Every refusal is an
//! [`ErrorKind::Input`](crate::ErrorKind::Input) error.
//!
//! No file system or OS calls: the browser build (wasm32) calls this module too.

use glam::{DMat3, DMat4, DVec4};
use raypatch_model::error::Quoted;

use crate::error::{Error, Result};
use raypatch_model::pinhole::Intrinsics;

pub use raypatch_model::PatchSize;

/// Largest |RᵀR − I| entry (and |det R − 1|) accepted for a rotation: poses stored as text with 6–7
/// significant digits pass, a scaled or sheared matrix does not.
pub const ROTATION_TOLERANCE: f64 = 1e-4;

/// Most frames of a sequence: a camera path, a motion, an interpolation, a turntable, repeated renders (each
/// frame takes at least milliseconds of GPU time).
pub const MAX_PATH_FRAMES: usize = 100_000;

/// `frames` when a sequence may have that many: 1 to [`MAX_PATH_FRAMES`].
pub fn check_frames(frames: usize) -> Result<usize> {
    match frames {
        1..=MAX_PATH_FRAMES => Ok(frames),
        _ => Err(Error::Input(format!("frames {frames}: expected 1 to {MAX_PATH_FRAMES}"))),
    }
}

/// The axes of a camera frame, for poses given as camera-to-world matrices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraAxes {
    /// x right, y down, the camera looks along +z (OpenCV, COLMAP; the MultiShapeNet look-at frame).
    OpenCv,
    /// x right, y up, the camera looks along −z (OpenGL, NeRF's `transforms.json`, Blender).
    OpenGl,
}

impl CameraAxes {
    pub const ALL: [CameraAxes; 2] = [CameraAxes::OpenGl, CameraAxes::OpenCv];

    /// The name each surface takes: `opengl` or `opencv`.
    pub fn name(self) -> &'static str {
        match self {
            CameraAxes::OpenGl => "opengl",
            CameraAxes::OpenCv => "opencv",
        }
    }

    /// A camera-to-world pose whose camera frame has these axes, with OpenCV axes instead (the same camera).
    /// The flip is its own inverse: it also turns an OpenCV pose into one with these axes.
    ///
    /// ```
    /// use glam::{DMat4, DVec3};
    /// use raypatch::CameraAxes;
    /// let opengl = DMat4::from_translation(DVec3::new(1.0, 2.0, 3.0));
    /// let opencv = CameraAxes::OpenGl.to_opencv(opengl);
    /// assert_eq!(opencv.z_axis.truncate(), DVec3::NEG_Z); // OpenGL cameras look along −z
    /// assert_eq!(CameraAxes::OpenGl.to_opencv(opencv), opengl);
    /// ```
    pub fn to_opencv(self, pose: DMat4) -> DMat4 {
        match self {
            CameraAxes::OpenCv => pose,
            CameraAxes::OpenGl => DMat4::from_cols(pose.x_axis, -pose.y_axis, -pose.z_axis, pose.w_axis),
        }
    }
}

impl std::str::FromStr for CameraAxes {
    type Err = Error;

    /// `opengl` or `opencv`.
    fn from_str(name: &str) -> Result<CameraAxes> {
        CameraAxes::ALL
            .into_iter()
            .find(|a| a.name() == name)
            .ok_or_else(|| Error::Input(format!("convention {:?}: expected \"opengl\" or \"opencv\"", Quoted(name))))
    }
}

/// What a pose given as numbers must be, for messages.
const POSE_NUMBERS: &str = "expected 16 finite numbers, a 4x4 camera-to-world matrix row by row";

/// A camera-to-world pose from 16 numbers, row by row: finite and rigid (see [`check_pose`]).
///
/// ```
/// let pose = raypatch::input::pose_from_numbers(&[1.0, 0.0, 0.0, 5.0, 0.0, 1.0, 0.0, 6.0, 0.0, 0.0, 1.0, 7.0, 0.0, 0.0, 0.0, 1.0])?;
/// assert_eq!(pose.w_axis.truncate(), glam::DVec3::new(5.0, 6.0, 7.0));
/// assert!(raypatch::input::pose_from_numbers(&[1.0, 2.0, 3.0]).unwrap_err().to_string().contains("pose: 3 numbers"));
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn pose_from_numbers(numbers: &[f64]) -> Result<DMat4> {
    let numbers: &[f64; 16] = numbers
        .try_into()
        .map_err(|_| Error::Input(format!("pose: {} numbers given: {POSE_NUMBERS}", numbers.len())))?;
    if let Some(i) = numbers.iter().position(|v| !v.is_finite()) {
        return Err(Error::Input(format!("pose: number {i} is {}: {POSE_NUMBERS}", numbers[i])));
    }
    let pose = DMat4::from_cols_array(numbers).transpose();
    check_pose(&pose)?;
    Ok(pose)
}

/// A camera-to-world pose from its 4 rows (see [`pose_from_numbers`]).
pub fn pose_from_rows(rows: &[[f64; 4]; 4]) -> Result<DMat4> {
    pose_from_numbers(rows.as_flattened())
}

/// A pose as 16 numbers, row by row (the form [`pose_from_numbers`] reads).
pub fn pose_numbers(pose: DMat4) -> [f64; 16] {
    pose.transpose().to_cols_array()
}

/// Checks that a camera-to-world pose is rigid: finite, its bottom row 0 0 0 1, its rotation orthonormal and
/// right-handed (within [`ROTATION_TOLERANCE`]): a scaled, sheared or mirrored pose is an error.
pub fn check_pose(m: &DMat4) -> Result<()> {
    if !m.is_finite() {
        return Err(Error::Input(format!(
            "pose {} holds NaN or infinity",
            Quoted(format_args!("{:?}", m.transpose().to_cols_array_2d()))
        )));
    }
    if (m.row(3) - DVec4::W).abs().max_element() > ROTATION_TOLERANCE {
        return Err(Error::Input(format!("pose bottom row is {}, expected 0 0 0 1", m.row(3))));
    }
    let r = DMat3::from_mat4(*m);
    let error = (r.transpose() * r - DMat3::IDENTITY).to_cols_array().iter().fold(0.0f64, |e, v| e.max(v.abs()));
    if error > ROTATION_TOLERANCE || (r.determinant() - 1.0).abs() > ROTATION_TOLERANCE {
        return Err(Error::Input(format!(
            "pose rotation is not orthonormal and right-handed \
             (max |RᵀR − I| = {error:.2e}, det = {:.6}, tolerance {ROTATION_TOLERANCE:e})",
            r.determinant()
        )));
    }
    Ok(())
}

/// A field of view, checked to lie in (0, 180) degrees (exclusive): what a focal length is made from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldOfView {
    radians: f64,
}

impl FieldOfView {
    /// A field of view in degrees; the reason, when it is not in (0, 180).
    pub fn degrees(degrees: f64) -> std::result::Result<FieldOfView, String> {
        FieldOfView::radians(degrees.to_radians())
            .map_err(|_| format!("{degrees}: expected a field of view in degrees in (0, 180)"))
    }

    /// A field of view in radians (NeRF's `camera_angle_x`); the reason, when it is not between 0 and π.
    pub fn radians(radians: f64) -> std::result::Result<FieldOfView, String> {
        if radians > 0.0 && radians < std::f64::consts::PI {
            Ok(FieldOfView { radians })
        } else {
            Err(format!("{radians}: expected a field of view in radians between 0 and π"))
        }
    }

    /// The focal length in pixels that spans `pixels` pixels with this field of view.
    pub fn focal(self, pixels: usize) -> f64 {
        (pixels as f64 / 2.0) / (self.radians / 2.0).tan()
    }
}

/// A camera's intrinsics resized to `width` x `height`, the one policy of every surface: resizing a camera keeps
/// its vertical field of view and the principal point's relative position. fy and fx scale by H'/H (pixels keep
/// their aspect), cx by W'/W, cy by H'/H; when the aspect is unchanged this is scaling each axis.
///
/// ```
/// use raypatch::{input, Intrinsics};
/// let k = Intrinsics { width: 80, height: 60, fx: 70.0, fy: 75.0, cx: 38.0, cy: 33.0 };
/// assert_eq!(input::resized_to(k, 160, 120)?, Intrinsics { width: 160, height: 120, fx: 140.0, fy: 150.0, cx: 76.0, cy: 66.0 });
/// let wide = input::resized_to(k, 160, 60)?; // a wider image: the same vertical view, more of it across
/// assert_eq!((wide.fx, wide.fy, wide.cx, wide.cy), (70.0, 75.0, 76.0, 33.0));
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn resized_to(k: Intrinsics, width: usize, height: usize) -> Result<Intrinsics> {
    crate::image::check_image_size(width, height).map_err(Error::Camera)?;
    let (sx, sy) = (width as f64 / k.width as f64, height as f64 / k.height as f64);
    Ok(Intrinsics { width, height, fx: k.fx * sy, fy: k.fy * sy, cx: k.cx * sx, cy: k.cy * sy })
}

/// Intrinsics at another image size ([`resized_to`]) and/or vertical field of view in degrees (square pixels,
/// focal length (height / 2) / tan(fov / 2), the principal point kept).
pub fn resized(intrinsics: Intrinsics, size: Option<(usize, usize)>, fov: Option<f64>) -> Result<Intrinsics> {
    let k = match size {
        Some((width, height)) => resized_to(intrinsics, width, height)?,
        None => intrinsics,
    };
    let Some(fov) = fov else { return Ok(k) };
    let focal = FieldOfView::degrees(fov).map_err(|e| Error::Camera(format!("fov {e}")))?.focal(k.height);
    Ok(Intrinsics { fx: focal, fy: focal, ..k })
}

/// Checks that a model whose patch sizes are `rule` renders `width` x `height`; else an error naming the
/// nearest sizes it does.
pub fn check_patch_size(rule: PatchSize, width: usize, height: usize) -> Result<()> {
    rule.check(width, height).map_err(Error::Input)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_are_finite_and_rigid_and_conventions_are_named() {
        let identity: Vec<f64> = DMat4::IDENTITY.to_cols_array().to_vec();
        assert_eq!(pose_from_numbers(&identity).unwrap(), DMat4::IDENTITY);
        let mut nan = identity.clone();
        nan[0] = f64::NAN;
        assert!(pose_from_numbers(&nan).unwrap_err().to_string().contains("pose: number 0 is NaN"));
        let mut scaled = identity.clone();
        scaled[0] = 2.0;
        let error = pose_from_numbers(&scaled).unwrap_err();
        assert!(error.to_string().contains("orthonormal") && error.kind() == crate::ErrorKind::Input, "{error}");
        let mut bottom = identity.clone();
        bottom[12] = 1.0;
        assert!(pose_from_numbers(&bottom).unwrap_err().to_string().contains("bottom row"));
        let rows = [[1.0, 0.0, 0.0, 5.0], [0.0, 1.0, 0.0, 6.0], [0.0, 0.0, 1.0, 7.0], [0.0, 0.0, 0.0, 1.0]];
        let pose = pose_from_rows(&rows).unwrap();
        assert_eq!(pose_numbers(pose).as_slice(), rows.as_flattened());
        assert_eq!("opencv".parse::<CameraAxes>().unwrap(), CameraAxes::OpenCv);
        let error = "blender".parse::<CameraAxes>().unwrap_err().to_string();
        assert!(error.contains("\"blender\"") && error.contains("\"opengl\" or \"opencv\""), "{error}");
    }

    #[test]
    fn fields_of_view_are_checked_once() {
        for bad in [0.0, 180.0, -5.0, f64::NAN, f64::INFINITY] {
            assert!(FieldOfView::degrees(bad).unwrap_err().contains("(0, 180)"), "{bad}");
        }
        assert!(FieldOfView::radians(std::f64::consts::PI).unwrap_err().contains("between 0 and π"));
        assert!((FieldOfView::degrees(90.0).unwrap().focal(60) - 30.0).abs() < 1e-12);
        let base = Intrinsics { width: 80, height: 60, fx: 70.0, fy: 70.0, cx: 40.0, cy: 30.0 };
        assert!(resized(base, None, Some(180.0)).unwrap_err().to_string().contains("fov 180"));
        assert!(check_frames(0).is_err() && check_frames(MAX_PATH_FRAMES + 1).is_err());
        assert_eq!(check_frames(MAX_PATH_FRAMES).unwrap(), MAX_PATH_FRAMES);
    }
}
