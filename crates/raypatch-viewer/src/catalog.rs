//! What the command line loaded, as the page sees it: models and scenes by index (never by path), their
//! cameras and input thumbnails, and the cameras the page asks for.

use glam::DMat4;
use raypatch::{input, Camera, CameraAxes, Intrinsics, Model, Output, PatchSize, RayKind, SceneData};
use serde_json::json;

/// The longest side of a rendered image, in pixels.
pub const MAX_SIDE: usize = 1024;
/// The most pixels a render may have (a render holds a render thread for its whole duration).
pub const MAX_PIXELS: usize = 512 * 512;

/// An output the page can show, by the name the page and the endpoint use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewOutput {
    Rgb,
    /// Depth coloured with the turbo map above its legend.
    Depth,
    /// OSRT object masks: each pixel coloured by its most-weighted slot.
    Masks,
}

impl ViewOutput {
    pub const ALL: [ViewOutput; 3] = [ViewOutput::Rgb, ViewOutput::Depth, ViewOutput::Masks];

    pub fn name(self) -> &'static str {
        match self {
            ViewOutput::Rgb => "rgb",
            ViewOutput::Depth => "depth",
            ViewOutput::Masks => "masks",
        }
    }

    /// The engine output it is drawn from.
    pub fn output(self) -> Output {
        match self {
            ViewOutput::Rgb => Output::Rgb,
            ViewOutput::Depth => Output::Depth,
            ViewOutput::Masks => Output::Segmentation,
        }
    }
}

/// A loaded model as the page describes it.
pub struct ModelEntry {
    pub name: String,
    pub family: String,
    /// The image sizes it renders: its patch size k, or any size.
    pub sizes: PatchSize,
    pub outputs: Vec<ViewOutput>,
    /// Its precision and the kernels its GEMMs run on (`Model::computes_as`).
    pub computes: String,
}

impl ModelEntry {
    pub fn of(model: &Model) -> ModelEntry {
        let outputs = ViewOutput::ALL.into_iter().filter(|o| model.outputs().contains(o.output())).collect();
        ModelEntry {
            name: file_name(model.path()),
            family: model.config().name(),
            sizes: model.target_sizes(),
            outputs,
            computes: model.computes_as(),
        }
    }
}

/// A loaded scene: its name, the camera whose size and intrinsics renders take (the first target view's, else
/// the first input's), every camera to jump to, and its input images as PNG thumbnails.
pub struct SceneEntry {
    pub name: String,
    pub reference: Camera,
    pub input_cameras: Vec<Camera>,
    pub target_cameras: Vec<Camera>,
    pub thumbnails: Vec<Vec<u8>>,
}

impl SceneEntry {
    pub fn of(name: &str, data: &SceneData) -> raypatch::Result<SceneEntry> {
        let input_cameras: Vec<Camera> = data.inputs.iter().map(|v| v.camera.clone()).collect();
        let target_cameras: Vec<Camera> = data.targets.iter().map(|t| t.camera.clone()).collect();
        let reference = target_cameras.first().or(input_cameras.first()).cloned().ok_or_else(|| {
            raypatch::Error::Views(format!("{name}: the scene has no camera to start the viewer from"))
        })?;
        let thumbnails = data.inputs.iter().map(|v| v.image.encode_png()).collect::<raypatch::Result<_>>()?;
        Ok(SceneEntry { name: file_name(name), reference, input_cameras, target_cameras, thumbnails })
    }

    /// The size renders take when none is asked for: the reference camera's, shrunk to fit the bounds on
    /// requests if it must, then the nearest size within them that the model renders.
    pub fn full_size(&self, sizes: PatchSize) -> (usize, usize) {
        let (w, h) = (self.reference.width() as f64, self.reference.height() as f64);
        let shrink = (MAX_SIDE as f64 / w.max(h)).min((MAX_PIXELS as f64 / (w * h)).sqrt()).min(1.0);
        nearest_within(sizes, (w * shrink) as usize, (h * shrink) as usize)
    }

    /// The size the page renders while the camera moves: half the full size, then the nearest size the model
    /// renders.
    pub fn preview_size(&self, sizes: PatchSize) -> (usize, usize) {
        let (w, h) = self.full_size(sizes);
        nearest_within(sizes, w / 2, h / 2)
    }

    /// The camera at `pose` (camera-to-world, OpenGL axes as NeRF's `transform_matrix`) with an image of
    /// `width` x `height`: the reference camera resized to that size (`raypatch::input::resized_to`: the same
    /// view at any resolution; exactly `render-frame --pose`'s camera at the reference size), or MultiShapeNet's
    /// when the scene's cameras are given by rays.
    pub fn camera(&self, pose: DMat4, width: usize, height: usize) -> raypatch::Result<Camera> {
        let intrinsics = match self.reference.as_pinhole() {
            Some((k, _)) => input::resized_to(k, width, height)?,
            None => Intrinsics::msn(width, height),
        };
        Camera::pinhole(intrinsics, pose, CameraAxes::OpenGl)
    }
}

/// The size nearest to `width` x `height` (each side at least 1) that the model renders within the bounds on
/// requests (`raypatch::PatchSize::nearest`).
fn nearest_within(sizes: PatchSize, width: usize, height: usize) -> (usize, usize) {
    let within = |&(w, h): &(usize, usize)| w.max(h) <= MAX_SIDE && w * h <= MAX_PIXELS;
    sizes.nearest(width.max(1), height.max(1)).into_iter().find(within).unwrap_or((sizes.k, sizes.k))
}

/// A camera's camera-to-world pose in OpenGL axes (the `pose` parameter's). A camera given by rays gets the
/// pose of the centred pinhole camera that makes them (`raypatch::fit_pinhole`; scenes' rays are unit
/// directions or, for DeFiNe scenes, points at depth 1); `None` when its rays span no width or height to fit
/// that camera to.
pub fn opengl_pose(camera: &Camera) -> Option<DMat4> {
    let points = camera.given_rays().is_some() && camera.check_rays(RayKind::UnitDepthPoint).is_ok();
    let kind = if points { RayKind::UnitDepthPoint } else { RayKind::UnitDirection };
    let (_, opencv) = raypatch::fit_pinhole(camera, kind).ok()?;
    Some(CameraAxes::OpenGl.to_opencv(opencv))
}

/// [`opengl_pose`] as the page reads it: 16 numbers, row by row.
fn pose_of(camera: &Camera) -> Option<[f64; 16]> {
    opengl_pose(camera).map(input::pose_numbers)
}

/// The last component of a path, so that the page never sees where files lie.
fn file_name(path: &str) -> String {
    std::path::Path::new(path).file_name().map_or_else(|| path.to_string(), |n| n.to_string_lossy().into_owned())
}

/// Everything the page needs to know, as the JSON of `GET /api/info`.
pub fn info_json(models: &[ModelEntry], scenes: &[SceneEntry], adapter: &str, limits: serde_json::Value) -> String {
    let cameras = |list: &[Camera]| -> Vec<serde_json::Value> {
        list.iter().map(|c| json!({ "pose": pose_of(c), "width": c.width(), "height": c.height() })).collect()
    };
    json!({
        "adapter": adapter,
        "models": models.iter().map(|m| json!({
            "name": m.name, "family": m.family, "k": m.sizes.k, "computes": m.computes,
            "outputs": m.outputs.iter().map(|o| o.name()).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "scenes": scenes.iter().map(|s| json!({
            "name": s.name,
            "width": s.reference.width(),
            "height": s.reference.height(),
            "pose": pose_of(&s.reference),
            "sizes": models.iter().map(|m| s.full_size(m.sizes)).collect::<Vec<_>>(),
            "preview_sizes": models.iter().map(|m| s.preview_size(m.sizes)).collect::<Vec<_>>(),
            "inputs": cameras(&s.input_cameras),
            "targets": cameras(&s.target_cameras),
        })).collect::<Vec<_>>(),
        "limits": limits,
    })
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// A pose read back from a camera builds the same camera, at its size and (scaled) at half of it.
    #[test]
    fn a_camera_pose_round_trips_and_scales() {
        let camera = Camera::msn(DVec3::new(4.0, -3.0, 2.0), 80, 60).unwrap();
        let scene = SceneEntry {
            name: "s".into(),
            reference: camera.clone(),
            input_cameras: vec![],
            target_cameras: vec![],
            thumbnails: vec![],
        };
        let pose = opengl_pose(&camera).unwrap();
        let again = scene.camera(pose, 80, 60).unwrap();
        for (a, b) in camera.rays().rays.iter().zip(&again.rays().rays) {
            assert!((*a - *b).abs().max_element() < 1e-6);
        }
        let half = scene.camera(pose, 40, 30).unwrap();
        let (full_rays, half_rays) = (camera.rays(), half.rays());
        // The half-size image's pixel (x, y) covers the full one's (2x..2x+1, 2y..2y+1): its centre ray lies
        // between those of the full image's pixels (2x, 2y) and (2x+1, 2y+1).
        let centre = (full_rays.rays[30 * 80 + 40] + full_rays.rays[31 * 80 + 41]).normalize();
        assert!((half_rays.rays[15 * 40 + 20] - centre).abs().max_element() < 1e-3);
        // A camera given by its rays gets the pose that makes them, whether directions or unit-depth points.
        for kind in [RayKind::UnitDirection, RayKind::UnitDepthPoint] {
            let given = Camera::from_rays(camera.position(), camera.rays_of(kind)).unwrap();
            let fitted = pose_of(&given).unwrap();
            assert!(fitted.iter().zip(pose_of(&camera).unwrap()).all(|(a, b)| (a - b).abs() < 1e-6), "{kind:?}");
        }
        let k = |k: usize| PatchSize { k, any_size: false };
        assert_eq!(
            (scene.full_size(k(4)), scene.full_size(k(8)), scene.full_size(k(64))),
            ((80, 60), (80, 56), (64, 64))
        );
        assert_eq!((scene.preview_size(k(4)), scene.preview_size(k(8))), ((40, 28), (40, 24)));
        assert_eq!(file_name("assets/models/a.safetensors"), "a.safetensors");
    }
}
