//! Cameras: pinhole intrinsics with a camera-to-world pose, the MultiShapeNet look-at convention, and explicit
//! ray grids. The model sees a camera as its centre and one ray per pixel centre (world frame, row 0 at the
//! top) of the model's [`RayKind`]: a unit direction (SRT, OSRT) or the point at unit depth (DeFiNe); cameras
//! that describe the same view give the same rays.

use std::sync::Arc;

use glam::{DMat3, DMat4, DVec3, Vec3};
use raypatch_model::pinhole::PinholeRays;
use raypatch_model::TargetRays;

use crate::error::{Error, Result};
pub use crate::input::CameraAxes;
pub use raypatch_model::RayKind;

/// Largest angle between a pixel centre's ray and the optical axis of a pinhole camera (degrees): a field of
/// view of up to 179.8°.
pub const MAX_RAY_ANGLE_DEGREES: f64 = 89.9;
/// Smallest field of view of a pinhole camera (degrees, between the outermost pixel centres, each way): below
/// it neighbouring pixels' float32 rays coincide.
pub const MIN_FIELD_OF_VIEW_DEGREES: f64 = 1e-3;
/// The same least spread for rays given as such: the largest distance between two of a grid's rays, relative
/// to their length (1e-3° in radians).
const MIN_RAY_SPREAD: f32 = (MIN_FIELD_OF_VIEW_DEGREES * std::f64::consts::PI / 180.0) as f32;

/// Pinhole intrinsics in pixels, for an image of `width` × `height` (see [`raypatch_model::pinhole::Intrinsics`]).
///
/// ```
/// use raypatch::Intrinsics;
/// let k = Intrinsics::msn(160, 120);
/// assert!((k.fx - 175.0).abs() < 1e-9 && k.fx == k.fy && (k.cx, k.cy) == (80.0, 60.0));
/// ```
pub use raypatch_model::pinhole::Intrinsics;
pub use raypatch_model::pinhole::{MSN_FOCAL_LENGTH, MSN_SENSOR_WIDTH};

/// Checks that these intrinsics make rays a model can use: finite values, positive focal lengths, every
/// ray through the image within [`MAX_RAY_ANGLE_DEGREES`] of the optical axis (a focal length too short for
/// the image, or a principal point far outside it, sends every ray along the image plane), and an image
/// spanning at least [`MIN_FIELD_OF_VIEW_DEGREES`] each way (a focal length too long makes every ray the
/// same).
fn check_intrinsics(k: &Intrinsics) -> Result<()> {
    crate::image::check_image_size(k.width, k.height).map_err(Error::Camera)?;
    let shown = format!("intrinsics fx={:?} fy={:?} cx={:?} cy={:?}", k.fx, k.fy, k.cx, k.cy);
    let values = [k.fx, k.fy, k.cx, k.cy];
    if values.iter().any(|v| !v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
        return Err(Error::Camera(format!("{shown}: expected finite values and positive focal lengths")));
    }
    // Tangents of the angles from the optical axis of the image's edges, each way.
    let edges = |focal: f64, centre: f64, pixels: usize| [-centre / focal, (pixels as f64 - centre) / focal];
    let (w, h) = (k.width, k.height);
    for (axis, [first, last]) in [("x", edges(k.fx, k.cx, w)), ("y", edges(k.fy, k.cy, h))] {
        let widest = first.abs().max(last.abs()).atan().to_degrees();
        if widest.is_nan() || widest > MAX_RAY_ANGLE_DEGREES {
            return Err(Error::Camera(format!(
                "{shown} on a {w}x{h} image: rays reach {widest:.4}° from the optical axis along {axis} (at most \
                 {MAX_RAY_ANGLE_DEGREES}°: the focal length is too short for the image, or the principal point \
                 too far from it)"
            )));
        }
        let field = (last.atan() - first.atan()).to_degrees();
        if field.is_nan() || field < MIN_FIELD_OF_VIEW_DEGREES {
            return Err(Error::Camera(format!(
                "{shown} on a {w}x{h} image: the image spans {field:.3e}° along {axis} (at least \
                 {MIN_FIELD_OF_VIEW_DEGREES}°: the focal length is too long for the image, every ray would be the \
                 same)"
            )));
        }
    }
    Ok(())
}

/// Rays in the world frame, row-major, row 0 at the top: unit directions, or for [`RayKind::UnitDepthPoint`]
/// the points at unit depth.
#[derive(Clone, Debug, PartialEq)]
pub struct RayGrid {
    /// Rays per row.
    pub width: usize,
    /// Rows of rays.
    pub height: usize,
    /// `width * height` rays, row-major: unit directions, or unit-depth points (see [`RayKind`]).
    pub rays: Vec<Vec3>,
}

#[derive(Clone, Debug, PartialEq)]
enum Projection {
    /// Rotation camera → world with OpenCV axes (columns: right, down, forward).
    Pinhole { intrinsics: Intrinsics, rotation: DMat3 },
    /// Rays given as such: one per pixel, or one per `per_ray` × `per_ray` patch, turned by `turn` (a camera
    /// [`orbited`](Camera::orbited) shares its grid with the camera it came from: a turntable of N frames keeps
    /// one grid, not N).
    Rays { grid: Arc<RayGrid>, per_ray: usize, turn: DMat3 },
}

/// A camera: where it is, the image it sees (`width` × `height`), and the rays through that image's pixels.
///
/// The three ways to make one agree: an MSN look-at camera, the same camera as intrinsics and a pose, and its
/// rays given explicitly all render the same image.
///
/// ```
/// use glam::DVec3;
/// use raypatch::{Camera, CameraAxes};
/// let msn = Camera::msn(DVec3::new(4.0, -3.0, 2.5), 48, 32)?;
/// let (intrinsics, pose) = msn.as_pinhole().unwrap();
/// let pinhole = Camera::pinhole(intrinsics, pose, CameraAxes::OpenCv)?;
/// let explicit = Camera::from_rays(msn.position(), msn.rays())?;
/// for (a, b) in msn.rays().rays.iter().zip(&pinhole.rays().rays) {
///     assert!((*a - *b).abs().max_element() < 1e-6);
/// }
/// assert_eq!(explicit.rays(), msn.rays());
/// # Ok::<(), raypatch::Error>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    position: DVec3,
    width: usize,
    height: usize,
    projection: Projection,
}

/// `grid`'s rays turned by `turn` (in f64, rounded to f32), or the grid itself when it is not turned.
fn turned(grid: &RayGrid, turn: DMat3) -> RayGrid {
    if turn == DMat3::IDENTITY {
        return grid.clone();
    }
    let rays = grid.rays.iter().map(|d| turned_ray(*d, turn)).collect();
    RayGrid { rays, ..*grid }
}

fn turned_ray(ray: Vec3, turn: DMat3) -> Vec3 {
    if turn == DMat3::IDENTITY {
        ray
    } else {
        (turn * ray.as_dvec3()).as_vec3()
    }
}

fn finite_vec(v: DVec3, what: &str) -> Result<DVec3> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::Camera(format!("{what} {v} is not finite")))
    }
}

impl Camera {
    /// This camera as the engine's one-view render target (its position, unit ray directions and image size);
    /// [`target_views_of`](Self::target_views_of) for a model of another [`RayKind`].
    pub fn target_views(&self) -> raypatch_model::TargetViews {
        self.target_views_of(RayKind::UnitDirection)
    }

    /// This camera as the engine's one-view render target, with rays of the model's kind (see
    /// [`rays_of`](Self::rays_of)): a pinhole camera's as the camera itself (a render makes its rays on the GPU:
    /// the same rays), given rays as values.
    pub fn target_views_of(&self, kind: RayKind) -> raypatch_model::TargetViews {
        let (width, height) = self.ray_grid_size();
        let rays = match self.pinhole_rays(kind) {
            Some(pinhole) => TargetRays::Pinhole(vec![pinhole]),
            None => {
                let mut rays = vec![0.0; width * height * 3];
                self.write_rays(kind, &mut rays);
                TargetRays::Given(rays)
            }
        };
        raypatch_model::TargetViews {
            count: 1,
            camera_pos: self.position().as_vec3().to_array().to_vec(),
            rays,
            rays_height: height,
            rays_width: width,
            declared_size: Some((self.height(), self.width())),
            images: None,
            masks: None,
        }
    }

    /// A pinhole camera's rays of `kind` in the form both the host and the GPU make them from
    /// ([`raypatch_model::pinhole`]); `None` for given rays.
    pub fn pinhole_rays(&self, kind: RayKind) -> Option<PinholeRays> {
        let Projection::Pinhole { intrinsics, rotation } = &self.projection else { return None };
        let axes = [rotation.x_axis, rotation.y_axis, rotation.z_axis].map(|a| a.to_array());
        Some(PinholeRays::new(kind, intrinsics, axes, self.position.to_array()))
    }

    /// A pinhole camera from intrinsics and a camera-to-world pose (rotation and camera centre; the bottom row
    /// must be 0 0 0 1) whose camera frame has the given axes. The pose must be rigid
    /// ([`input::check_pose`](crate::input::check_pose)): a scaled, sheared or mirrored pose is an error.
    pub fn pinhole(intrinsics: Intrinsics, camera_to_world: DMat4, axes: CameraAxes) -> Result<Camera> {
        check_intrinsics(&intrinsics)?;
        crate::input::check_pose(&camera_to_world)?;
        let m = axes.to_opencv(camera_to_world);
        Ok(Camera {
            position: m.w_axis.truncate(),
            width: intrinsics.width,
            height: intrinsics.height,
            projection: Projection::Pinhole { intrinsics, rotation: DMat3::from_mat4(m) },
        })
    }

    /// A pinhole camera at `eye` looking at `target`, with `up` pointing up in the image (the MSN convention:
    /// image right = forward × up, image down = forward × right).
    pub fn look_at(eye: DVec3, target: DVec3, up: DVec3, intrinsics: Intrinsics) -> Result<Camera> {
        check_intrinsics(&intrinsics)?;
        let (eye, target, up) = (finite_vec(eye, "eye")?, finite_vec(target, "target")?, finite_vec(up, "up")?);
        let forward =
            (target - eye).try_normalize().ok_or_else(|| Error::Camera(format!("eye {eye} is the target")))?;
        let right = forward
            .cross(up)
            .try_normalize()
            .ok_or_else(|| Error::Camera(format!("camera at {eye} looks along the up axis {up}")))?;
        let down = forward.cross(right).normalize();
        Ok(Camera {
            position: eye,
            width: intrinsics.width,
            height: intrinsics.height,
            projection: Projection::Pinhole { intrinsics, rotation: DMat3::from_cols(right, down, forward) },
        })
    }

    /// A MultiShapeNet camera (the official `get_camera_rays`): at `position`, looking at the world origin
    /// with +z up, focal length 0.035 and sensor width 0.032, square pixels.
    pub fn msn(position: DVec3, width: usize, height: usize) -> Result<Camera> {
        Camera::look_at(position, DVec3::ZERO, DVec3::Z, Intrinsics::msn(width, height))
    }

    /// A camera given by its centre and one ray per pixel (the image size is the grid's). Rays must be finite
    /// and non-zero; they are used as given, whatever kind a model asks for ([`check_rays`](Self::check_rays)
    /// checks them against a kind).
    pub fn from_rays(position: DVec3, grid: RayGrid) -> Result<Camera> {
        Camera::from_patch_rays(position, grid, 1)
    }

    /// A camera given by its centre and one ray per `k` × `k` patch (the patch rays a Ray-Patch model with
    /// patch size `k` queries); the image is `k` times the grid in each dimension.
    pub fn from_patch_rays(position: DVec3, grid: RayGrid, k: usize) -> Result<Camera> {
        let position = finite_vec(position, "position")?;
        if grid.width == 0 || grid.height == 0 || k == 0 {
            return Err(Error::Camera(format!("ray grid {}x{} (k={k}) is empty", grid.width, grid.height)));
        }
        if Some(grid.rays.len()) != grid.width.checked_mul(grid.height) {
            return Err(Error::Camera(format!(
                "ray grid has {} rays, expected width x height = {}x{}",
                grid.rays.len(),
                grid.width,
                grid.height
            )));
        }
        if let Some(i) = grid.rays.iter().position(|d| !d.is_finite() || d.length() < 1e-6) {
            return Err(Error::Camera(format!("ray {i} is {}: expected a finite, non-zero direction", grid.rays[i])));
        }
        // Rays that all coincide see one point: every pixel would get the same colour.
        let first = grid.rays[0];
        let spread = grid.rays.iter().map(|d| (*d - first).length()).fold(0.0f32, f32::max);
        if grid.rays.len() > 1 && spread < MIN_RAY_SPREAD * first.length() {
            return Err(Error::Camera(format!(
                "the {}x{} rays are degenerate: all within {spread:e} of ray 0 {first} (they must spread at least \
                 {MIN_RAY_SPREAD:e} of its length apart, the field of view of {MIN_FIELD_OF_VIEW_DEGREES}°)",
                grid.width, grid.height
            )));
        }
        let (width, height) = (grid.width.saturating_mul(k), grid.height.saturating_mul(k));
        crate::image::check_image_size(width, height).map_err(Error::Camera)?;
        let projection = Projection::Rays { grid: Arc::new(grid), per_ray: k, turn: DMat3::IDENTITY };
        Ok(Camera { position, width, height, projection })
    }

    /// The camera centre in the world frame.
    pub fn position(&self) -> DVec3 {
        self.position
    }

    /// Width of the image in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height of the image in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The intrinsics and the camera-to-world pose (OpenCV axes) of a pinhole camera; `None` for cameras
    /// given by rays.
    pub fn as_pinhole(&self) -> Option<(Intrinsics, DMat4)> {
        match &self.projection {
            Projection::Pinhole { intrinsics, rotation } => Some((
                *intrinsics,
                DMat4::from_cols(
                    rotation.x_axis.extend(0.0),
                    rotation.y_axis.extend(0.0),
                    rotation.z_axis.extend(0.0),
                    self.position.extend(1.0),
                ),
            )),
            Projection::Rays { .. } => None,
        }
    }

    /// Pixels per ray along each axis: 1, or `k` for cameras made with [`from_patch_rays`](Self::from_patch_rays).
    pub fn pixels_per_ray(&self) -> usize {
        match &self.projection {
            Projection::Pinhole { .. } => 1,
            Projection::Rays { per_ray, .. } => *per_ray,
        }
    }

    /// The camera's rays as unit directions ([`rays_of`](Self::rays_of) with [`RayKind::UnitDirection`]), or the
    /// grid it was given.
    pub fn rays(&self) -> RayGrid {
        self.rays_of(RayKind::UnitDirection)
    }

    /// The camera's rays of `kind` through the pixel centres p = [u + 0.5, v + 0.5, 1] (computed in f64, rounded
    /// to f32), or the grid it was given, as given. With R the camera-to-world rotation (OpenCV axes), K the
    /// intrinsics and c the centre, each pixel's vector R·K⁻¹p (depth 1 along the camera's forward axis) gives
    /// the unit direction normalize(R·K⁻¹p) or the unit-depth point c + R·K⁻¹p.
    ///
    /// ```
    /// use glam::DVec3;
    /// use raypatch::{Camera, RayKind};
    /// let camera = Camera::msn(DVec3::new(4.0, -3.0, 2.5), 4, 2)?;
    /// let (directions, points) = (camera.rays(), camera.rays_of(RayKind::UnitDepthPoint));
    /// let (_, pose) = camera.as_pinhole().unwrap();
    /// let forward = pose.z_axis.truncate();
    /// for (d, p) in directions.rays.iter().zip(&points.rays) {
    ///     let offset = p.as_dvec3() - camera.position();
    ///     assert!((offset.dot(forward) - 1.0).abs() < 1e-6); // at unit depth
    ///     assert!((offset.normalize() - d.as_dvec3()).length() < 1e-6); // along the same ray
    /// }
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn rays_of(&self, kind: RayKind) -> RayGrid {
        match &self.projection {
            Projection::Rays { grid, turn, .. } => turned(grid, *turn),
            Projection::Pinhole { .. } => {
                let mut values = vec![0.0; self.width * self.height * 3];
                self.write_rays(kind, &mut values);
                let rays = values.chunks_exact(3).map(Vec3::from_slice).collect();
                RayGrid { width: self.width, height: self.height, rays }
            }
        }
    }

    /// The size of the camera's ray grid: the image's, or the given patch grid's (width, height).
    pub fn ray_grid_size(&self) -> (usize, usize) {
        match &self.projection {
            Projection::Rays { grid, .. } => (grid.width, grid.height),
            Projection::Pinhole { .. } => (self.width, self.height),
        }
    }

    /// Writes the rays [`rays_of`](Self::rays_of) gives, row-major, 3 floats a ray, into `out` (the
    /// [`ray_grid_size`](Self::ray_grid_size)'s rays × 3 values), without building the grid: a pinhole camera's
    /// large images are computed a band of rows per core, each ray as the GPU makes it
    /// ([`raypatch_model::pinhole`]).
    pub fn write_rays(&self, kind: RayKind, out: &mut [f32]) {
        let (width, height) = self.ray_grid_size();
        assert_eq!(out.len(), width * height * 3, "write_rays: room for {width}x{height} rays");
        match &self.projection {
            Projection::Rays { grid, turn, .. } => {
                for (o, d) in out.chunks_exact_mut(3).zip(&grid.rays) {
                    o.copy_from_slice(&turned_ray(*d, *turn).to_array());
                }
            }
            Projection::Pinhole { .. } => self.pinhole_rays(kind).expect("a pinhole camera").write(out),
        }
    }

    /// Checks the rays this camera was given against `kind` (see [`raypatch_model::rays::check_ray_kind`]):
    /// the reason, one line, when they are not of that kind. A pinhole camera's rays are made of the kind asked
    /// for, so they always pass.
    ///
    /// ```
    /// use glam::DVec3;
    /// use raypatch::{Camera, RayKind};
    /// let msn = Camera::msn(DVec3::new(4.0, -3.0, 2.5), 8, 6)?;
    /// let points = Camera::from_rays(msn.position(), msn.rays_of(RayKind::UnitDepthPoint))?;
    /// assert!(points.check_rays(RayKind::UnitDepthPoint).is_ok());
    /// let error = points.check_rays(RayKind::UnitDirection).unwrap_err();
    /// assert!(error.contains("this model takes unit ray directions") && error.contains("look like unit-depth points"));
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn check_rays(&self, kind: RayKind) -> std::result::Result<(), String> {
        let Some(grid) = self.given_rays() else {
            return Ok(());
        };
        let position = self.position.as_vec3().to_array();
        raypatch_model::rays::check_ray_kind(kind, position, grid.width, grid.height, |i| grid.rays[i].to_array())
    }

    /// The rays the camera was built from ([`from_rays`](Self::from_rays), [`from_patch_rays`](Self::from_patch_rays)),
    /// turned as the camera was ([`orbited`](Self::orbited)); `None` for a pinhole camera, whose rays
    /// [`rays_of`](Self::rays_of) computes.
    pub fn given_rays(&self) -> Option<RayGrid> {
        match &self.projection {
            Projection::Rays { grid, turn, .. } => Some(turned(grid, *turn)),
            Projection::Pinhole { .. } => None,
        }
    }

    /// This camera turned by `degrees` about the world z axis through the origin: a turntable step for z-up
    /// scenes centred on the origin (MultiShapeNet, NeRF's Blender scenes). Positive angles turn from +x
    /// towards +y. Given rays turn with it, unit directions and unit-depth points alike (the turn is linear).
    ///
    /// ```
    /// use glam::DVec3;
    /// use raypatch::Camera;
    /// let a = Camera::msn(DVec3::new(5.0, 0.0, 2.0), 32, 32)?;
    /// let b = a.orbited(90.0);
    /// assert!((b.position() - DVec3::new(0.0, 5.0, 2.0)).length() < 1e-12);
    /// let c = Camera::msn(DVec3::new(0.0, 5.0, 2.0), 32, 32)?;
    /// for (x, y) in b.rays().rays.iter().zip(&c.rays().rays) {
    ///     assert!((*x - *y).abs().max_element() < 1e-6);
    /// }
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn orbited(&self, degrees: f64) -> Camera {
        let turn = DMat3::from_rotation_z(degrees.to_radians());
        let projection = match &self.projection {
            Projection::Pinhole { intrinsics, rotation } => {
                Projection::Pinhole { intrinsics: *intrinsics, rotation: turn * *rotation }
            }
            Projection::Rays { grid, per_ray, turn: before } => {
                Projection::Rays { grid: Arc::clone(grid), per_ray: *per_ray, turn: turn * *before }
            }
        };
        Camera { position: turn * self.position, projection, ..*self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pinhole camera with an OpenGL pose and off-centre intrinsics: each kind of ray is R·K⁻¹p made a unit
    /// direction or offset by the centre, with R in OpenCV axes.
    #[test]
    fn rays_of_each_kind_come_from_one_pinhole_computation() {
        let k = Intrinsics { width: 5, height: 3, fx: 4.0, fy: 5.0, cx: 2.0, cy: 1.25 };
        let turn = DMat3::from_rotation_z(0.4) * DMat3::from_rotation_x(1.1);
        let centre = DVec3::new(3.0, -1.0, 2.0);
        let gl = DMat4::from_cols(
            turn.x_axis.extend(0.0),
            turn.y_axis.extend(0.0),
            turn.z_axis.extend(0.0),
            centre.extend(1.0),
        );
        let camera = Camera::pinhole(k, gl, CameraAxes::OpenGl).unwrap();
        let cv = DMat3::from_cols(turn.x_axis, -turn.y_axis, -turn.z_axis);
        let (directions, points) = (camera.rays(), camera.rays_of(RayKind::UnitDepthPoint));
        assert_eq!(directions, camera.rays_of(RayKind::UnitDirection));
        for (i, (d, p)) in directions.rays.iter().zip(&points.rays).enumerate() {
            let (u, v) = ((i % 5) as f64 + 0.5, (i / 5) as f64 + 0.5);
            let local = cv * DVec3::new((u - 2.0) / 4.0, (v - 1.25) / 5.0, 1.0);
            assert!((p.as_dvec3() - (centre + local)).length() < 1e-6, "point {i}");
            assert!((d.as_dvec3() - local.normalize()).length() < 1e-6, "direction {i}");
            // At depth 1 along the camera's forward axis (OpenGL's −z).
            assert!(((p.as_dvec3() - centre).dot(-turn.z_axis) - 1.0).abs() < 1e-6);
        }
        let views = camera.target_views_of(RayKind::UnitDepthPoint);
        assert_eq!(views.ray_values()[..3], points.rays[0].to_array());
        assert_eq!(camera.target_views().ray_values()[..3], directions.rays[0].to_array());
        // Given rays are used as given, whatever the kind, and orbit as points do.
        let given = Camera::from_rays(centre, points.clone()).unwrap();
        assert_eq!(given.rays_of(RayKind::UnitDirection), points);
        assert_eq!(given.check_rays(RayKind::UnitDepthPoint), Ok(()));
        let (a, b) = (given.orbited(35.0), camera.orbited(35.0).rays_of(RayKind::UnitDepthPoint));
        for (x, y) in a.rays().rays.iter().zip(&b.rays) {
            assert!((*x - *y).abs().max_element() < 1e-5);
        }
        assert_eq!(a.check_rays(RayKind::UnitDepthPoint), Ok(()));
        assert!(a.check_rays(RayKind::UnitDirection).unwrap_err().contains("unit ray directions"));
        assert_eq!(camera.check_rays(RayKind::UnitDirection), Ok(()), "a pinhole camera makes either kind");
    }

    /// A large image's rays, written a band of rows per core, are each pixel's own ray: no band shifted,
    /// repeated or left out (the image is above PARALLEL_RAYS, its height not a multiple of the cores), and
    /// within one float32 rounding of the float64 ray.
    #[test]
    fn rays_written_in_bands_are_each_pixels_own() {
        let (width, height) = (331, 257);
        assert!(width * height >= raypatch_model::pinhole::PARALLEL_RAYS);
        let k = Intrinsics { width, height, fx: 300.0, fy: 310.0, cx: 160.0, cy: 131.5 };
        let camera = Camera::look_at(DVec3::new(4.0, -3.0, 2.5), DVec3::ZERO, DVec3::Z, k).unwrap();
        let (_, pose) = camera.as_pinhole().unwrap();
        let rotation = DMat3::from_mat4(pose);
        for kind in [RayKind::UnitDirection, RayKind::UnitDepthPoint] {
            let pinhole = camera.pinhole_rays(kind).unwrap();
            let mut written = vec![f32::NAN; width * height * 3];
            camera.write_rays(kind, &mut written);
            for (i, ray) in written.chunks_exact(3).enumerate() {
                let (row, column) = (i / width, i % width);
                assert_eq!(ray, pinhole.ray(row, column), "{kind:?} ray {i}");
                let (u, v) = (column as f64 + 0.5, row as f64 + 0.5);
                let world = rotation * DVec3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
                let want = match kind {
                    RayKind::UnitDirection => world.normalize(),
                    RayKind::UnitDepthPoint => camera.position() + world,
                };
                let off = (Vec3::from_slice(ray).as_dvec3() - want).abs().max_element();
                assert!(off <= want.abs().max_element() * f64::from(f32::EPSILON), "{kind:?} ray {i}: {off}");
            }
        }
    }
}
