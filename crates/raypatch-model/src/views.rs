//! Scene files: posed input views and the target cameras to render (docs/FORMATS.md).

use std::borrow::Cow;
use std::path::Path;

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::patch_size::PatchSize;
use crate::pinhole::PinholeRays;
use crate::tensor_file::{HostTensor, TensorFile};

/// Posed input views: images `[N,H,W,3]` in [0,1], camera centres `[N,3]`, unit rays `[N,H,W,3]`.
#[derive(Clone, Debug)]
pub struct InputViews {
    pub count: usize,
    pub height: usize,
    pub width: usize,
    pub images: Vec<f32>,
    pub camera_pos: Vec<f32>,
    pub rays: Vec<f32>,
}

/// Target cameras: centres `[T,3]` and their rays on a `rays_height` × `rays_width` grid, full resolution or
/// one ray per patch.
#[derive(Clone, Debug)]
pub struct TargetViews {
    pub count: usize,
    pub camera_pos: Vec<f32>,
    pub rays: TargetRays,
    pub rays_height: usize,
    pub rays_width: usize,
    /// The size of the image to render when the file says it (`target_images` or `target_size` metadata).
    pub declared_size: Option<(usize, usize)>,
    /// Ground truth `[T,Ht,Wt,3]`, when the file has it.
    pub images: Option<Vec<f32>>,
    /// Ground-truth object ids `[T,Ht,Wt]` (0 = background), when the file has `target_masks`.
    pub masks: Option<Vec<u32>>,
}

/// The rays of target views: given as values, or as pinhole cameras whose rays are made where they are used
/// (a render makes them on the GPU: nothing per pixel crosses the bus).
#[derive(Clone, Debug)]
pub enum TargetRays {
    /// `[T, rays_height, rays_width, 3]`: a scene file's, or an API caller's.
    Given(Vec<f32>),
    /// One pinhole camera per view, one ray per pixel.
    Pinhole(Vec<PinholeRays>),
}

impl TargetRays {
    /// The rays as values, `(height, width)` rays a view.
    pub fn values(&self, (height, width): (usize, usize)) -> Cow<'_, [f32]> {
        match self {
            TargetRays::Given(values) => values.into(),
            TargetRays::Pinhole(cameras) => {
                let mut values = vec![0.0; cameras.len() * height * width * 3];
                for (camera, out) in cameras.iter().zip(values.chunks_exact_mut(height * width * 3)) {
                    camera.write(out);
                }
                values.into()
            }
        }
    }
}

/// How a target ray grid maps onto the image to render, for a given patch size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TargetGrid {
    pub height: usize,
    pub width: usize,
    pub rays: RaySource,
}

/// Where a render's rays come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RaySource {
    /// Given, one per pixel.
    Pixels,
    /// Given, one per k×k patch (used as given).
    Patches,
    /// Made from pinhole cameras ([`TargetRays::Pinhole`]), one per pixel.
    Pinhole,
}

#[derive(Clone, Debug)]
pub struct SceneFile {
    pub path: String,
    pub inputs: InputViews,
    pub targets: TargetViews,
    /// Ground-truth depth `[T,Ht,Wt]` in metres (`target_depth`; 0 or less = no depth at that pixel), when the
    /// file has it: what depth metrics score a model's depth against.
    pub target_depth: Option<Vec<f32>>,
}

fn shape_err(path: &str, key: &str, expected: String, found: &[usize]) -> ModelError {
    ModelError::Value {
        path: path.to_string(),
        key: key.to_string(),
        reason: format!("shape {found:?}, expected {expected}"),
    }
}

/// Reads `key` and checks it is `[.., 3]` with the given leading dimensions (None = any).
fn read(file: &TensorFile, key: &str, lead: &[Option<usize>], what: &str) -> Result<HostTensor, ModelError> {
    let t = file.f32(key)?;
    let ok = t.shape.len() == lead.len() + 1
        && t.shape[lead.len()] == 3
        && lead.iter().zip(&t.shape).all(|(want, &got)| want.is_none_or(|w| w == got));
    if !ok {
        return Err(shape_err(&file.path, key, what.to_string(), &t.shape));
    }
    Ok(t)
}

/// Most views, input or target, a scene may have (as a frame folder may have frames): each target view is a
/// render, so more is a mistake or an attack that would run for days.
pub const MAX_VIEWS: usize = 10_000;

fn check_view_count(path: &str, key: &str, views: usize) -> Result<(), ModelError> {
    if views > MAX_VIEWS {
        return Err(ModelError::Value {
            path: path.into(),
            key: key.into(),
            reason: format!("{views} views; a scene may have at most {MAX_VIEWS}"),
        });
    }
    Ok(())
}

/// What a scene path must be, for messages.
const SCENE_FILE: &str = "a scene .safetensors file (docs/FORMATS.md) or a folder with transforms.json";

pub fn load_scene(path: impl AsRef<Path>) -> Result<SceneFile, ModelError> {
    scene_of(&TensorFile::open_as(path.as_ref(), SCENE_FILE)?)
}

/// [`load_scene`] of a file's bytes (a browser's files); `name` names it in messages.
pub fn scene_from_bytes(name: &str, bytes: &[u8]) -> Result<SceneFile, ModelError> {
    scene_of(&TensorFile::parse_as(name, bytes, SCENE_FILE)?)
}

/// The scene in a file that should be one (a model file is named as such).
fn scene_of(file: &TensorFile) -> Result<SceneFile, ModelError> {
    if !file.contains("input_images") && file.metadata.contains_key("config") {
        return Err(ModelError::Value {
            path: file.path.clone(),
            key: "input_images".into(),
            reason: format!("missing: this is a model file, expected {SCENE_FILE}"),
        });
    }
    scene_from_file(file)
}

pub fn scene_from_file(file: &TensorFile) -> Result<SceneFile, ModelError> {
    let path = file.path.as_str();
    let images = read(file, "input_images", &[None, None, None], "[N,H,W,3]")?;
    let (n, h, w) = (images.shape[0], images.shape[1], images.shape[2]);
    check_view_count(path, "input_images", n)?;
    if n == 0 || h == 0 || w == 0 {
        return Err(ModelError::Value {
            path: path.into(),
            key: "input_images".into(),
            reason: format!("shape {:?}: the scene needs at least one non-empty input view", images.shape),
        });
    }
    check_unit_interval(path, "input_images", &images.data)?;
    let camera_pos = read(file, "input_camera_pos", &[Some(n)], &format!("[{n},3] (one position per input view)"))?;
    let rays = read(file, "input_rays", &[Some(n), Some(h), Some(w)], &format!("[{n},{h},{w},3] (like input_images)"))?;
    check_unit_rays(path, "input_rays", &rays.data)?;

    let target_pos = read(file, "target_camera_pos", &[None], "[T,3]")?;
    let t = target_pos.shape[0];
    check_view_count(path, "target_camera_pos", t)?;
    if t == 0 {
        return Err(ModelError::Value {
            path: path.into(),
            key: "target_camera_pos".into(),
            reason: "no target view".into(),
        });
    }
    let target_rays =
        read(file, "target_rays", &[Some(t), None, None], &format!("[{t},Ht,Wt,3] (one grid per target view)"))?;
    check_unit_rays(path, "target_rays", &target_rays.data)?;
    let target_images = if file.contains("target_images") {
        let images = read(file, "target_images", &[Some(t), None, None], &format!("[{t},Ht,Wt,3]"))?;
        check_unit_interval(path, "target_images", &images.data)?;
        Some(images)
    } else {
        None
    };
    let declared_size = match (&target_images, file.metadata.get("target_size")) {
        (Some(img), _) => Some((img.shape[1], img.shape[2])),
        (None, Some(text)) => Some(parse_size(text).ok_or_else(|| ModelError::Value {
            path: path.into(),
            key: "target_size".into(),
            reason: format!("metadata value {text:?}, expected \"HEIGHTxWIDTH\""),
        })?),
        (None, None) => None,
    };

    let masks = if file.contains("target_masks") {
        let size = declared_size.ok_or_else(|| ModelError::Value {
            path: path.into(),
            key: "target_masks".into(),
            reason: "needs the target size: `target_images` or the `target_size` metadata".into(),
        })?;
        Some(read_masks(file, t, size)?)
    } else {
        None
    };
    let target_depth = if file.contains("target_depth") {
        // The target size, as for rendering: declared, else the ray grid's.
        let size = declared_size.unwrap_or((target_rays.shape[1], target_rays.shape[2]));
        Some(read_depth(file, t, size)?)
    } else {
        None
    };

    Ok(SceneFile {
        path: path.to_string(),
        inputs: InputViews {
            count: n,
            height: h,
            width: w,
            images: images.data,
            camera_pos: camera_pos.data,
            rays: rays.data,
        },
        targets: TargetViews {
            count: t,
            camera_pos: target_pos.data,
            rays_height: target_rays.shape[1],
            rays_width: target_rays.shape[2],
            rays: TargetRays::Given(target_rays.data),
            declared_size,
            images: target_images.map(|t| t.data),
            masks,
        },
        target_depth,
    })
}

/// Most object ids a mask may hold (a bound on the contingency tables of FG-ARI).
pub const MAX_OBJECT_ID: i64 = 65535;

/// `target_masks`: object ids `[T,Ht,Wt]` of an integer dtype (0 = background; the MSN-Easy mask PNGs,
/// `tools/data/make_scenes.py`), or one-hot `[T,Ht,Wt,G]` (F32 or integer) with channel 0 the background, as the
/// official loader builds them (the id is the channel holding the largest value; all zeros is background).
fn read_masks(file: &TensorFile, t: usize, (h, w): (usize, usize)) -> Result<Vec<u32>, ModelError> {
    let key = "target_masks";
    let expected = format!("[{t},{h},{w}] object ids (0 = background) or [{t},{h},{w},G] one-hot");
    let shape = file.shape(key).unwrap_or_default().to_vec();
    let err = |reason: String| ModelError::Value { path: file.path.clone(), key: key.into(), reason };
    if shape.len() < 3 || shape[..3] != [t, h, w] || shape.len() > 4 || shape.get(3) == Some(&0) {
        return Err(shape_err(&file.path, key, expected, &shape));
    }
    let values: Vec<f64> = match file.integers(key) {
        Ok((_, v)) => v.into_iter().map(|x| x as f64).collect(),
        Err(_) => file.f32(key)?.data.into_iter().map(f64::from).collect(),
    };
    if shape.len() == 3 {
        return values
            .iter()
            .enumerate()
            .map(|(i, &v)| match v {
                v if v.fract() == 0.0 && (0.0..=MAX_OBJECT_ID as f64).contains(&v) => Ok(v as u32),
                v => Err(err(format!("element {i} is {v}, expected an object id from 0 to {MAX_OBJECT_ID}"))),
            })
            .collect();
    }
    let groups = shape[3];
    Ok(values
        .chunks_exact(groups)
        .map(|one_hot| {
            let (best, max) = one_hot.iter().enumerate().fold((0, 0.0), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
            if max > 0.0 {
                best as u32
            } else {
                0
            }
        })
        .collect())
}

/// `target_depth`: F32 `[T,Ht,Wt]`, metres along the camera's forward axis or along the ray as the model
/// predicts it; 0 (or less) where there is no ground truth, as ScanNet's depth PNGs hold 0 there.
fn read_depth(file: &TensorFile, t: usize, (h, w): (usize, usize)) -> Result<Vec<f32>, ModelError> {
    let depth = file.f32("target_depth")?;
    if depth.shape != [t, h, w] {
        let expected = format!("[{t},{h},{w}] (metres per target pixel, 0 = none; the target size is height x width)");
        return Err(shape_err(&file.path, "target_depth", expected, &depth.shape));
    }
    Ok(depth.data)
}

/// Images are RGB in [0, 1] (a 0-255 image would give meaningless renders and metrics).
fn check_unit_interval(path: &str, key: &str, values: &[f32]) -> Result<(), ModelError> {
    match values.iter().position(|v| !(0.0..=1.0).contains(v)) {
        None => Ok(()),
        Some(i) => Err(ModelError::Value {
            path: path.into(),
            key: key.into(),
            reason: format!("element {i} is {}, expected RGB values in [0, 1]", values[i]),
        }),
    }
}

/// Rays are directions; a zero vector cannot be encoded meaningfully and is a sign of a broken file.
fn check_unit_rays(path: &str, key: &str, rays: &[f32]) -> Result<(), ModelError> {
    for (i, r) in rays.chunks_exact(3).enumerate() {
        let norm = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        if norm < 1e-6 {
            return Err(ModelError::Value {
                path: path.into(),
                key: key.into(),
                reason: format!("ray {i} has zero length"),
            });
        }
    }
    Ok(())
}

fn parse_size(text: &str) -> Option<(usize, usize)> {
    let (h, w) = text.split_once('x')?;
    Some((h.trim().parse().ok()?, w.trim().parse().ok()?))
}

impl InputViews {
    /// Checks that a model can encode these views: at least one non-empty view, and buffers that hold
    /// `count` views of `height`×`width`. Any size is encodable, as in PyTorch: each of the model's conv
    /// blocks ends in a stride-2 3×3 convolution with padding 1, which maps a side s to ceil(s / 2), so with
    /// the official 3 blocks 60×80 inputs (height × width) give 30×40, 15×20, then 8×10 tokens per view.
    pub fn check(&self, path: &str) -> Result<(), ModelError> {
        let err = |key: &str, reason: String| Err(ModelError::Value { path: path.into(), key: key.into(), reason });
        let (n, h, w) = (self.count, self.height, self.width);
        if n == 0 || h == 0 || w == 0 {
            return err(
                "input_images",
                format!("{n} views of {w}x{h} (width x height): the model needs at least one non-empty input view"),
            );
        }
        for (key, len, want, what) in [
            ("input_images", self.images.len(), n * h * w * 3, "N*H*W*3"),
            ("input_camera_pos", self.camera_pos.len(), n * 3, "N*3"),
            ("input_rays", self.rays.len(), n * h * w * 3, "N*H*W*3"),
        ] {
            if len != want {
                return err(key, format!("{len} values, expected {what} = {want} for {n} views of {w}x{h}"));
            }
        }
        for (key, values) in
            [("input_images", &self.images), ("input_camera_pos", &self.camera_pos), ("input_rays", &self.rays)]
        {
            if let Some(reason) = non_finite(values, values.len() / n) {
                return err(key, reason);
            }
        }
        Ok(())
    }
}

/// Where `values` (`per_view` a view) first hold NaN or infinity, as "view V: value I is X": no such value may
/// reach a kernel (a GPU's sin or cos of NaN need not be NaN, so the outputs would not always show it).
fn non_finite(values: &[f32], per_view: usize) -> Option<String> {
    let i = values.iter().position(|v| !v.is_finite())?;
    let (view, at) = (i / per_view.max(1), i % per_view.max(1));
    Some(format!("view {view}: value {at} is {}; every value must be finite", values[i]))
}

impl TargetViews {
    /// Target view `v` alone (its camera and rays; no ground truth), as a batch of one.
    pub fn view(&self, v: usize) -> TargetViews {
        let rays = match &self.rays {
            TargetRays::Given(values) => {
                let per_view = values.len() / self.count;
                TargetRays::Given(values[v * per_view..(v + 1) * per_view].to_vec())
            }
            TargetRays::Pinhole(cameras) => TargetRays::Pinhole(vec![cameras[v].clone()]),
        };
        TargetViews {
            count: 1,
            camera_pos: self.camera_pos[3 * v..3 * v + 3].to_vec(),
            rays,
            rays_height: self.rays_height,
            rays_width: self.rays_width,
            declared_size: self.declared_size,
            images: None,
            masks: None,
        }
    }

    /// Appends `more`'s views (of the same ray grid) after these: pinhole cameras stay cameras when both are,
    /// else every ray becomes a value.
    pub fn append(&mut self, more: TargetViews) {
        assert_eq!((self.rays_height, self.rays_width), (more.rays_height, more.rays_width), "append: one ray grid");
        self.camera_pos.extend(more.camera_pos);
        let rays = std::mem::replace(&mut self.rays, TargetRays::Given(Vec::new()));
        self.rays = match (rays, more.rays) {
            (TargetRays::Pinhole(mut a), TargetRays::Pinhole(b)) => {
                a.extend(b);
                TargetRays::Pinhole(a)
            }
            (a, b) => {
                let grid = (self.rays_height, self.rays_width);
                TargetRays::Given([a.values(grid), b.values(grid)].concat())
            }
        };
        self.count += more.count;
    }

    /// The rays as values, `[T, rays_height, rays_width, 3]`: given ones as they are, a pinhole camera's made
    /// here (the same values a render makes on the GPU).
    pub fn ray_values(&self) -> Cow<'_, [f32]> {
        self.rays.values((self.rays_height, self.rays_width))
    }

    /// Checks that every camera position and ray is finite. The engine checks as it uploads them (in the same
    /// pass) and calls this only to name the value.
    pub fn check_finite(&self, path: &str) -> Result<(), ModelError> {
        let err = |key: &str, reason| Err(ModelError::Value { path: path.into(), key: key.into(), reason });
        if let Some(reason) = non_finite(&self.camera_pos, 3) {
            return err("target_camera_pos", reason);
        }
        match &self.rays {
            TargetRays::Given(values) => {
                if let Some(reason) = non_finite(values, values.len() / self.count.max(1)) {
                    return err("target_rays", reason);
                }
            }
            TargetRays::Pinhole(cameras) => {
                if let Some(v) = cameras.iter().position(|c| !c.is_finite()) {
                    let reason = format!("view {v}: the pinhole camera's rays are not finite in float32 (too far out)");
                    return err("target_rays", reason);
                }
            }
        }
        Ok(())
    }

    /// The image size and ray resolution of these target views for a model (see [`grid`](Self::grid)).
    pub fn grid_for(&self, config: &ModelConfig, path: &str) -> Result<TargetGrid, ModelError> {
        self.grid(config.patch_size(), config.resizes_output(), path)
    }

    /// Resolves the image size and whether the rays are per patch, for patch size `k` (docs/FORMATS.md).
    /// A model that resizes its output (the official `rp_kwargs.h_out/w_out`) renders sizes that `k` does not
    /// divide: it decodes the `(height / k) × (width / k)` patch grid and resizes the result.
    pub fn grid(&self, k: usize, resizes_output: bool, path: &str) -> Result<TargetGrid, ModelError> {
        let (rh, rw) = (self.rays_height, self.rays_width);
        let (height, width) = self.declared_size.unwrap_or((rh, rw));
        let err = |reason: String| ModelError::Value { path: path.into(), key: "target_rays".into(), reason };
        let rays_fit = match &self.rays {
            TargetRays::Given(values) => values.len() == self.count * rh * rw * 3,
            TargetRays::Pinhole(cameras) => {
                cameras.len() == self.count && cameras.iter().all(|c| (c.height(), c.width()) == (rh, rw))
            }
        };
        if self.count == 0 || self.camera_pos.len() != self.count * 3 || !rays_fit {
            let rays = match &self.rays {
                TargetRays::Given(values) => format!("{} ray values", values.len()),
                TargetRays::Pinhole(cameras) => format!("{} pinhole cameras", cameras.len()),
            };
            return Err(err(format!(
                "{} camera positions and {rays} for {} views of {rw}x{rh} rays",
                self.camera_pos.len() / 3,
                self.count
            )));
        }
        PatchSize { k, any_size: resizes_output }.check(width, height).map_err(err)?;
        if height < k || width < k {
            return Err(err(format!(
                "target size {width}x{height} (width x height) is smaller than one patch (k={k})"
            )));
        }
        let pinhole = matches!(self.rays, TargetRays::Pinhole(_));
        let rays = if (rh, rw) == (height, width) {
            if pinhole {
                RaySource::Pinhole
            } else {
                RaySource::Pixels
            }
        } else if (rh, rw) == (height / k, width / k) && !pinhole {
            RaySource::Patches
        } else {
            return Err(err(format!(
                "ray grid {rw}x{rh} matches neither the target size {width}x{height} nor its patch grid {}x{} \
                 (width x height, k={k}{})",
                width / k,
                height / k,
                if pinhole { "; a pinhole camera's rays are one per pixel" } else { "" }
            )));
        };
        Ok(TargetGrid { height, width, rays })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_given_as_bytes_get_the_messages_of_files_given_as_paths() {
        let dir = std::env::temp_dir().join(format!("raypatch-bytes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let zip = b"PK\x03\x04 not really a zip";
        let path = dir.join("bad.safetensors");
        std::fs::write(&path, zip).unwrap();
        let by_path = load_scene(&path).unwrap_err().to_string();
        let by_bytes = scene_from_bytes(&path.display().to_string(), zip).unwrap_err().to_string();
        assert_eq!(by_bytes, by_path);
        assert!(by_bytes.contains("expected a scene .safetensors file"), "{by_bytes}");
        let by_path = crate::load_model(&path).unwrap_err().to_string();
        let by_bytes = crate::weights::model_from_bytes(&path.display().to_string(), zip).unwrap_err().to_string();
        assert_eq!(by_bytes, by_path);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn target_depth_is_read_and_its_shape_checked() {
        let (t, h, w) = (1usize, 2usize, 3usize);
        let tensor = |shape: &[usize], values: &[f32]| {
            let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            (shape.to_vec(), bytes)
        };
        let file = |depth_shape: &[usize]| {
            let n = depth_shape.iter().product::<usize>();
            let mut tensors = [
                ("input_images", tensor(&[1, h, w, 3], &vec![0.5; h * w * 3])),
                ("input_camera_pos", tensor(&[1, 3], &[0.0, 0.0, 0.0])),
                ("input_rays", tensor(&[1, h, w, 3], &[0.0, 0.0, 1.0].repeat(h * w))),
                ("target_camera_pos", tensor(&[t, 3], &[0.0, 0.0, 0.0])),
                ("target_rays", tensor(&[t, h, w, 3], &[0.0, 0.0, 1.0].repeat(h * w))),
                ("target_depth", tensor(depth_shape, &(0..n).map(|i| i as f32 * 0.5).collect::<Vec<_>>())),
            ];
            tensors.sort_by_key(|(k, _)| *k);
            let views: Vec<(&str, safetensors::tensor::TensorView)> = tensors
                .iter()
                .map(|(k, (shape, bytes))| {
                    (*k, safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape.clone(), bytes).unwrap())
                })
                .collect();
            let bytes = safetensors::serialize(views, None).unwrap();
            scene_from_file(&TensorFile::parse("s.safetensors", &bytes).unwrap())
        };
        let scene = file(&[t, h, w]).unwrap();
        assert_eq!(scene.target_depth, Some(vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5]));
        let e = file(&[t, w, h]).unwrap_err().to_string();
        assert!(e.contains("s.safetensors") && e.contains("`target_depth`") && e.contains("expected [1,2,3]"), "{e}");
    }
}
