//! Posed views from disk: raypatch scene files (safetensors) and folders of PNGs with a NeRF-style
//! `transforms.json`.

use std::borrow::Cow;
use std::path::{Component, Path, PathBuf};

use glam::{DMat4, Vec3};
use raypatch_model::error::Quoted;
use serde_json::Value;

use crate::camera::{Camera, CameraAxes, Intrinsics, RayGrid, RayKind};
use crate::error::{Error, Result};
use crate::image::{Image, MAX_PNG_BYTES};
use crate::render::InputView;

/// Where a [`SceneData`] came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SceneSource {
    /// A scene safetensors file (docs/FORMATS.md): separate input and target views.
    File(PathBuf),
    /// A folder with `transforms.json`: every frame is both an input and a target candidate.
    Frames(PathBuf),
}

/// A camera to render, with its ground truth when known.
#[derive(Clone, Debug)]
pub struct TargetView {
    /// The camera to render from.
    pub camera: Camera,
    /// The ground truth, when the scene has it (`target_images`, or the frame's PNG).
    pub image: Option<Image>,
    /// Ground-truth object ids `[height, width]` row-major (0 = background), when the scene has
    /// `target_masks`: what `--metrics` scores the segmentation against (FG-ARI).
    pub masks: Option<Vec<u32>>,
    /// Ground-truth depth `[height, width]` row-major in metres, when the scene has it (`target_depth`, or a
    /// frame's `depth_file_path`); 0 where there is none: what `--metrics` scores depth against.
    pub depth: Option<Vec<f32>>,
}

/// Posed views read from disk.
///
/// ```
/// let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k2");
/// let data = raypatch::SceneData::load(format!("{golden}/scene.safetensors"))?;
/// assert_eq!((data.inputs.len(), data.targets.len()), (1, 2));
/// assert!(data.targets[0].image.is_some());
/// # Ok::<(), raypatch::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct SceneData {
    /// The file or folder the views were read from.
    pub source: SceneSource,
    /// Posed images to encode.
    pub inputs: Vec<InputView>,
    /// Cameras to render.
    pub targets: Vec<TargetView>,
    /// Every file that was read (outputs must not overwrite them).
    pub files: Vec<PathBuf>,
}

impl SceneData {
    /// Reads a scene safetensors file, or a folder holding `transforms.json` and its images.
    pub fn load(path: impl AsRef<Path>) -> Result<SceneData> {
        let path = path.as_ref();
        if path.is_dir() {
            SceneData::from_frames(path)
        } else {
            SceneData::from_file(path)
        }
    }

    /// Reads a scene safetensors file: input images, camera centres and rays; target centres and rays (one per
    /// pixel, or one per patch with the image size in `target_images` or the `target_size` metadata).
    pub fn from_file(path: impl AsRef<Path>) -> Result<SceneData> {
        let path = path.as_ref();
        let mut data = SceneData::from_scene_file(raypatch_model::load_scene(path)?)?;
        data.files = vec![path.to_path_buf()];
        Ok(data)
    }

    /// Reads a scene from the bytes of a scene file (e.g. one embedded in a program); `name` stands for the
    /// file in messages.
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<SceneData> {
        SceneData::from_scene_file(raypatch_model::views::scene_from_bytes(name, bytes)?)
    }

    fn from_scene_file(file: raypatch_model::SceneFile) -> Result<SceneData> {
        let (n, h, w) = (file.inputs.count, file.inputs.height, file.inputs.width);
        let position = |pos: &[f32], i: usize| Vec3::from_slice(&pos[3 * i..3 * i + 3]).as_dvec3();
        let grid = |rays: &[f32], i: usize, gh: usize, gw: usize| RayGrid {
            width: gw,
            height: gh,
            rays: rays[i * gh * gw * 3..(i + 1) * gh * gw * 3].chunks_exact(3).map(Vec3::from_slice).collect(),
        };
        // A camera's error names the file, the tensor of its rays and the view.
        let in_file = |key: &str, what: &str, i: usize| {
            let path = file.path.clone();
            let key = key.to_string();
            let what = format!("{what} {i}");
            move |e: Error| match e {
                Error::Camera(reason) => {
                    Error::Model(raypatch_model::ModelError::Value { path, key, reason: format!("{what}: {reason}") })
                }
                other => other,
            }
        };
        let inputs = (0..n)
            .map(|i| {
                let pixels = file.inputs.images[i * h * w * 3..(i + 1) * h * w * 3].to_vec();
                let camera = Camera::from_rays(position(&file.inputs.camera_pos, i), grid(&file.inputs.rays, i, h, w))
                    .map_err(in_file("input_rays", "input view", i))?;
                Ok(InputView { image: Image::new(w, h, pixels)?, camera })
            })
            .collect::<Result<Vec<_>>>()?;
        let t = &file.targets;
        let (gh, gw) = (t.rays_height, t.rays_width);
        let (th, tw) = t.declared_size.unwrap_or((gh, gw));
        // Rays per pixel, or per k×k patch when the declared image is k times the ray grid.
        let per_ray = if (th, tw) == (gh, gw) {
            1
        } else if th % gh == 0 && tw % gw == 0 && th / gh == tw / gw {
            th / gh
        } else {
            return Err(Error::Model(raypatch_model::ModelError::Value {
                path: file.path.clone(),
                key: "target_rays".into(),
                reason: format!(
                    "ray grid {gw}x{gh} is neither the target size {tw}x{th} nor that size divided by a patch size \
                     (width x height)"
                ),
            }));
        };
        let rays = t.ray_values();
        let targets = (0..t.count)
            .map(|i| {
                let camera = Camera::from_patch_rays(position(&t.camera_pos, i), grid(&rays, i, gh, gw), per_ray)
                    .map_err(in_file("target_rays", "target view", i))?;
                let image = t
                    .images
                    .as_ref()
                    .map(|all| Image::new(tw, th, all[i * th * tw * 3..(i + 1) * th * tw * 3].to_vec()));
                let masks = t.masks.as_ref().map(|all| all[i * th * tw..(i + 1) * th * tw].to_vec());
                let depth = file.target_depth.as_ref().map(|all| all[i * th * tw..(i + 1) * th * tw].to_vec());
                Ok(TargetView { camera, image: image.transpose()?, masks, depth })
            })
            .collect::<Result<Vec<_>>>()?;
        let source = SceneSource::File(PathBuf::from(&file.path));
        Ok(SceneData { source, inputs, targets, files: Vec::new() })
    }

    /// Checks the rays of every camera given by rays (a scene file's `input_rays` and `target_rays`) against
    /// the kind a model takes (see [`Camera::check_rays`]); an error naming the file, the tensor, the view and
    /// the ray. Pinhole cameras (frame folders) are made of the kind a model asks for and always pass.
    ///
    /// ```
    /// use raypatch::RayKind;
    /// let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k2");
    /// let data = raypatch::SceneData::load(format!("{golden}/scene.safetensors"))?;
    /// data.check_rays(RayKind::UnitDirection)?;
    /// let error = data.check_rays(RayKind::UnitDepthPoint).unwrap_err().to_string();
    /// assert!(error.contains("tensor `input_rays`: view 0") && error.contains("this model takes unit-depth points"));
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn check_rays(&self, kind: RayKind) -> Result<()> {
        let path = match &self.source {
            SceneSource::File(path) => path.display().to_string(),
            SceneSource::Frames(_) => return Ok(()),
        };
        let inputs: Vec<&Camera> = self.inputs.iter().map(|v| &v.camera).collect();
        let targets: Vec<&Camera> = self.targets.iter().map(|v| &v.camera).collect();
        for (key, cameras) in [("input_rays", inputs), ("target_rays", targets)] {
            for (i, camera) in cameras.into_iter().enumerate() {
                camera.check_rays(kind).map_err(|reason| {
                    Error::Model(raypatch_model::ModelError::Value {
                        path: path.clone(),
                        key: key.into(),
                        reason: format!("view {i}: {reason}"),
                    })
                })?;
            }
        }
        Ok(())
    }

    /// Reads a folder with a NeRF-style `transforms.json`: intrinsics as `camera_angle_x` (and optionally
    /// `camera_angle_y`) or `fl_x`/`fl_y`/`cx`/`cy` (top level or per frame; `w`/`h` are checked against the
    /// images), and per frame a `file_path` (relative to the folder, `.png` added when missing) and a 4×4
    /// camera-to-world `transform_matrix` with OpenGL axes (x right, y up, looking along −z). All images must
    /// have the same size. Every frame becomes both an input view and a target view (with its image). A frame
    /// may name a ground-truth depth map, `depth_file_path`: a 16-bit (or 8-bit) grey PNG of the image's size
    /// holding millimetres along the camera's forward axis, 0 where there is no depth (ScanNet's depth PNGs),
    /// read in metres into the target view's depth.
    pub fn from_frames(dir: impl AsRef<Path>) -> Result<SceneData> {
        let dir = dir.as_ref();
        let json_path = dir.join("transforms.json");
        let text = read_json_text(&json_path)?;
        let mut data = SceneData::frames_from(dir, &text, &Folder(dir))?;
        data.files.insert(0, json_path);
        Ok(data)
    }

    /// Reads a frames folder as [`from_frames`](Self::from_frames) does, from bytes: `transforms_json` and the
    /// files it names, `file(name)` giving the bytes of the file at `name` (relative to the folder, `/`
    /// between its parts, no `./`) where there is one (e.g. a folder a page was given). `folder` names the
    /// folder in messages. Nothing is read from disk: a frame's file is one `file` gives, or the scene is
    /// refused.
    ///
    /// ```
    /// let json = br#"{"camera_angle_x": 0.8, "frames": [{"file_path": "r_0",
    ///     "transform_matrix": [[1,0,0,0], [0,0,-1,-6], [0,1,0,1], [0,0,0,1]]}]}"#;
    /// let png = raypatch::Image::new(4, 2, vec![0.5; 24])?.encode_png()?;
    /// let data = raypatch::SceneData::from_frame_bytes("scene", json, |name| (name == "r_0.png").then_some(&png[..]))?;
    /// assert_eq!((data.inputs.len(), data.targets[0].camera.width()), (1, 4));
    /// let error = raypatch::SceneData::from_frame_bytes("scene", b"{", |_| None).unwrap_err().to_string();
    /// assert!(error.starts_with("scene/transforms.json: not valid JSON"));
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn from_frame_bytes<'a>(
        folder: &str,
        transforms_json: &[u8],
        file: impl Fn(&str) -> Option<&'a [u8]>,
    ) -> Result<SceneData> {
        let dir = Path::new(folder);
        let json_path = dir.join("transforms.json");
        let text = raypatch_model::files::within(transforms_json.len() as u64, MAX_JSON_BYTES)
            .and_then(|()| raypatch_model::files::as_text(transforms_json))
            .map_err(|e| Error::io(&json_path, "cannot read", e.into()))?;
        let mut data = SceneData::frames_from(dir, text, &Named { dir: dir.to_path_buf(), file })?;
        data.files.clear(); // nothing on disk to protect
        Ok(data)
    }

    /// The views of the `transforms.json` of folder `dir` (its text `text`, its files from `files`): the one
    /// reading of frames folders, on disk or given as bytes.
    fn frames_from(dir: &Path, text: &str, files: &dyn FrameFiles<'_>) -> Result<SceneData> {
        let json_path = dir.join("transforms.json");
        let shown = json_path.display().to_string();
        let err = |reason: String| Error::Cameras { path: shown.clone(), reason };
        let root: Value = serde_json::from_str(text).map_err(|e| err(format!("not valid JSON: {e}")))?;
        let frames = root.get("frames").and_then(Value::as_array).ok_or_else(|| err("no `frames` list".into()))?;
        if frames.is_empty() {
            return Err(err("`frames` is empty: the scene has no view".into()));
        }
        if frames.len() > MAX_FRAMES {
            return Err(err(format!("{} frames; at most {MAX_FRAMES} are read", frames.len())));
        }
        let mut inputs: Vec<InputView> = Vec::with_capacity(frames.len());
        let mut depths: Vec<Option<Vec<f32>>> = Vec::with_capacity(frames.len());
        let mut read = Vec::with_capacity(frames.len());
        let mut pixels = 0usize;
        for (i, frame) in frames.iter().enumerate() {
            let name = frame
                .get("file_path")
                .and_then(Value::as_str)
                .ok_or_else(|| err(format!("frame {i}: no `file_path`")))?;
            let file =
                frame_image_path(files, name).map_err(|reason| err(format!("frame {i}: `file_path` {reason}")))?;
            let image = Image::decode_png(&file.display().to_string(), &files.read(&file, MAX_PNG_BYTES)?)?;
            pixels += image.width() * image.height();
            if pixels > MAX_SCENE_PIXELS {
                return Err(err(format!(
                    "frames 0 to {i} hold more than {MAX_SCENE_PIXELS} pixels, the most a scene may have"
                )));
            }
            read.push(file);
            if let Some(first) = inputs.first() {
                let (w, h) = (first.image.width(), first.image.height());
                if (image.width(), image.height()) != (w, h) {
                    return Err(err(format!(
                        "frame {i} ({name}) is {}x{}, frame 0 is {w}x{h}: all images must have the same size",
                        image.width(),
                        image.height()
                    )));
                }
            }
            let camera = nerf_camera(&root, frame, image.width(), image.height())
                .map_err(|reason| err(format!("frame {i} ({name}): {reason}")))?;
            depths.push(match frame.get("depth_file_path") {
                None | Some(Value::Null) => None,
                Some(value) => {
                    let depth_name = value.as_str().ok_or_else(|| {
                        err(format!("frame {i}: `depth_file_path` is {}, expected a file name", Quoted(value)))
                    })?;
                    let depth_file = frame_image_path(files, depth_name)
                        .map_err(|reason| err(format!("frame {i}: `depth_file_path` {reason}")))?;
                    let bytes = files.read(&depth_file, MAX_DEPTH_PNG_BYTES)?;
                    let depth = decode_depth_png(&depth_file, &bytes, image.width(), image.height())?;
                    read.push(depth_file);
                    Some(depth)
                }
            });
            inputs.push(InputView { image, camera });
        }
        let targets = inputs
            .iter()
            .zip(depths)
            .map(|(v, depth)| TargetView { camera: v.camera.clone(), image: Some(v.image.clone()), masks: None, depth })
            .collect();
        Ok(SceneData { source: SceneSource::Frames(dir.to_path_buf()), inputs, targets, files: read })
    }
}

/// Where the files a `transforms.json` names come from: its folder on disk, or files given by name.
trait FrameFiles<'a> {
    /// The file `name` (as the JSON writes it) stands for, as messages show it, or why there is none.
    fn resolve(&self, name: &str) -> std::result::Result<PathBuf, String>;
    /// The bytes of a file [`resolve`](Self::resolve) gave, at most `max_bytes`.
    fn read(&self, file: &Path, max_bytes: u64) -> Result<Cow<'a, [u8]>>;
}

/// A frames folder on disk: names resolve inside it (see [`raypatch_model::files::resolve_inside`]).
struct Folder<'a>(&'a Path);

impl<'a> FrameFiles<'a> for Folder<'_> {
    fn resolve(&self, name: &str) -> std::result::Result<PathBuf, String> {
        raypatch_model::files::resolve_inside(self.0, name)
    }

    fn read(&self, file: &Path, max_bytes: u64) -> Result<Cow<'a, [u8]>> {
        let bytes = raypatch_model::files::read_regular(file, max_bytes)
            .map_err(|e| Error::io(file, "cannot read", e.into()))?;
        Ok(Cow::Owned(bytes))
    }
}

/// A frames folder given as files by name (`file`, see [`SceneData::from_frame_bytes`]), shown as in `dir`.
struct Named<F> {
    dir: PathBuf,
    file: F,
}

impl<'a, F: Fn(&str) -> Option<&'a [u8]>> Named<F> {
    /// The name `file` takes for a path under `dir` (parts joined by `/`).
    fn key(&self, file: &Path) -> String {
        let relative = file.strip_prefix(&self.dir).unwrap_or(file);
        relative.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/")
    }
}

impl<'a, F: Fn(&str) -> Option<&'a [u8]>> FrameFiles<'a> for Named<F> {
    fn resolve(&self, name: &str) -> std::result::Result<PathBuf, String> {
        let relative = raypatch_model::files::check_relative(name)?;
        let file =
            self.dir.join(relative.components().filter(|c| matches!(c, Component::Normal(_))).collect::<PathBuf>());
        match (self.file)(&self.key(&file)) {
            Some(_) => Ok(file),
            None => Err(format!("{:?}: no such file in the scene folder", Quoted(name))),
        }
    }

    fn read(&self, file: &Path, max_bytes: u64) -> Result<Cow<'a, [u8]>> {
        let bytes = (self.file)(&self.key(file)).unwrap_or_default();
        raypatch_model::files::within(bytes.len() as u64, max_bytes)
            .map_err(|e| Error::io(file, "cannot read", e.into()))?;
        Ok(Cow::Borrowed(bytes))
    }
}

/// Integer depth units per metre in a frame's `depth_file_path` PNG: millimetres, as ScanNet stores depth.
const DEPTH_PNG_UNITS_PER_METRE: f32 = 1000.0;

/// Decodes a depth PNG (grey, 16 or 8 bits; millimetres, 0 = no depth) of a `width` × `height` frame, in metres.
fn decode_depth_png(path: &Path, bytes: &[u8], width: usize, height: usize) -> Result<Vec<f32>> {
    let shown = path.display().to_string();
    let bad = |reason: String| Error::Image { path: shown.clone(), reason };
    let reader = || image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Png);
    let (w, h) = reader().into_dimensions().map_err(|e| bad(format!("not a readable PNG: {e}")))?;
    if (w as usize, h as usize) != (width, height) {
        return Err(bad(format!(
            "depth map is {w}x{h}, its frame's image is {width}x{height}: they must be the same size"
        )));
    }
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(w as u64 * h as u64 * 8 + (1 << 20));
    let mut reader = reader();
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| bad(format!("not a readable PNG: {e}")))?;
    let values: Vec<u16> = match decoded {
        image::DynamicImage::ImageLuma16(grey) => grey.into_raw(),
        image::DynamicImage::ImageLuma8(grey) => grey.into_raw().into_iter().map(u16::from).collect(),
        other => {
            return Err(bad(format!(
                "a {:?} PNG; a depth map is a grey PNG (16-bit: millimetres, 0 = no depth)",
                other.color()
            )))
        }
    };
    Ok(values.into_iter().map(|mm| f32::from(mm) / DEPTH_PNG_UNITS_PER_METRE).collect())
}

/// Largest depth PNG read.
const MAX_DEPTH_PNG_BYTES: u64 = 1 << 30;

/// Most frames read from a `transforms.json`.
pub const MAX_FRAMES: usize = raypatch_model::views::MAX_VIEWS;
/// Most pixels over all the frames of a folder (1 GiB of f32 RGB).
pub const MAX_SCENE_PIXELS: usize = 1 << 26;
/// Largest JSON file read (a `transforms.json` of 10 000 frames is a few MB).
const MAX_JSON_BYTES: u64 = 64 << 20;

pub(crate) fn read_json_text(path: &Path) -> Result<String> {
    raypatch_model::files::read_regular_text(path, MAX_JSON_BYTES).map_err(|e| Error::io(path, "cannot read", e.into()))
}

/// The image of a frame: the file `name` names among `files`, with `.png` added when `name` has no extension
/// and no such file exists.
fn frame_image_path(files: &dyn FrameFiles, name: &str) -> std::result::Result<PathBuf, String> {
    let as_given = files.resolve(name);
    if as_given.is_err() && Path::new(name).extension().is_none() {
        return files.resolve(&format!("{name}.png"));
    }
    as_given
}

/// Reads a camera-to-world pose file: JSON with a 4×4 `transform_matrix` (OpenGL axes, as in
/// `transforms.json`) and optionally intrinsics and `w`/`h` in the same keys; without intrinsics the camera
/// takes those of `like` when it is a pinhole camera, else MultiShapeNet's at `like`'s size.
///
/// ```
/// use glam::DVec3;
/// let path = std::env::temp_dir().join("raypatch-doc-pose.json");
/// std::fs::write(&path, r#"{"camera_angle_x": 0.8,
///     "transform_matrix": [[1,0,0,0], [0,0,-1,-6], [0,1,0,1], [0,0,0,1]]}"#).unwrap();
/// let like = raypatch::Camera::msn(DVec3::new(5.0, 0.0, 1.0), 32, 24)?;
/// let camera = raypatch::load_pose(&path, &like)?;
/// assert_eq!((camera.position(), camera.width()), (DVec3::new(0.0, -6.0, 1.0), 32));
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn load_pose(path: impl AsRef<Path>, like: &Camera) -> Result<Camera> {
    let path = path.as_ref();
    let err = |reason: String| Error::Cameras { path: path.display().to_string(), reason };
    let text = read_json_text(path)?;
    let root: Value = serde_json::from_str(&text).map_err(|e| err(format!("not valid JSON: {e}")))?;
    let has_intrinsics = ["camera_angle_x", "fl_x"].iter().any(|k| root.get(k).is_some());
    let (w, h) = (number(&root, &root, "w").map_err(&err)?, number(&root, &root, "h").map_err(&err)?);
    let size = |v: Option<f64>, key: &str, default: usize| v.map_or(Ok(default), |v| pixels(key, v).map_err(&err));
    let (width, height) = (size(w, "w", like.width())?, size(h, "h", like.height())?);
    let camera = if has_intrinsics {
        nerf_camera(&root, &root, width, height)
    } else {
        let intrinsics = match like.as_pinhole() {
            Some((k, _)) if (k.width, k.height) == (width, height) => k,
            _ => Intrinsics::msn(width, height),
        };
        json_pose(&root, "transform_matrix")
            .and_then(|m| Camera::pinhole(intrinsics, m, CameraAxes::OpenGl).map_err(|e| e.to_string()))
    };
    camera.map_err(err)
}

/// `v`, the value under `key`, as a whole number of pixels: 1 to [`MAX_IMAGE_SIDE`](crate::MAX_IMAGE_SIDE).
pub(crate) fn pixels(key: &str, v: f64) -> std::result::Result<usize, String> {
    if v.fract() == 0.0 && (1.0..=crate::MAX_IMAGE_SIDE as f64).contains(&v) {
        Ok(v as usize)
    } else {
        Err(format!("`{key}` is {v}, expected a whole number of pixels, 1 to {}", crate::MAX_IMAGE_SIDE))
    }
}

/// A number under `key`, from the frame or else the top level.
pub(crate) fn number(root: &Value, frame: &Value, key: &str) -> std::result::Result<Option<f64>, String> {
    match frame.get(key).or_else(|| root.get(key)) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => match v.as_f64() {
            Some(x) if x.is_finite() => Ok(Some(x)),
            _ => Err(format!("`{key}` is {}, expected a finite number", Quoted(v))),
        },
    }
}

/// The camera of one `transforms.json` frame on an image of `width` × `height`.
fn nerf_camera(root: &Value, frame: &Value, width: usize, height: usize) -> std::result::Result<Camera, String> {
    let get = |key| number(root, frame, key);
    for (key, actual) in [("w", width), ("h", height)] {
        if let Some(v) = get(key)? {
            if v != actual as f64 {
                return Err(format!("`{key}` is {v} but the image is {width}x{height}"));
            }
        }
    }
    let focal_from_angle = |key: &str, angle: f64, size: usize| {
        let fov = crate::input::FieldOfView::radians(angle).map_err(|e| format!("`{key}` is {e}"))?;
        Ok::<_, String>(fov.focal(size))
    };
    let fx = match (get("fl_x")?, get("camera_angle_x")?) {
        (Some(f), _) => f,
        (None, Some(angle)) => focal_from_angle("camera_angle_x", angle, width)?,
        (None, None) => return Err("no intrinsics: expected `camera_angle_x` or `fl_x`".into()),
    };
    let fy = match (get("fl_y")?, get("camera_angle_y")?) {
        (Some(f), _) => f,
        (None, Some(angle)) => focal_from_angle("camera_angle_y", angle, height)?,
        (None, None) => fx,
    };
    let cx = get("cx")?.unwrap_or(width as f64 / 2.0);
    let cy = get("cy")?.unwrap_or(height as f64 / 2.0);
    let intrinsics = Intrinsics { width, height, fx, fy, cx, cy };
    Camera::pinhole(intrinsics, json_pose(frame, "transform_matrix")?, CameraAxes::OpenGl).map_err(|e| e.to_string())
}

/// A camera-to-world pose under `key` of a JSON object, as 4 rows of 4 numbers or 16 numbers row by row (the
/// JSON read here, the numbers checked by `crate::input`): `transform_matrix` in `transforms.json` and pose
/// files, `camera_to_world` in camera paths.
pub(crate) fn json_pose(object: &Value, key: &str) -> std::result::Result<DMat4, String> {
    let expected = "4 rows of 4 finite numbers, or 16 finite numbers row by row";
    let value = object.get(key).ok_or_else(|| format!("no `{key}` (expected {expected})"))?;
    let numbers: Vec<&Value> = match value.as_array() {
        Some(rows) if rows.len() == 4 && rows.iter().all(|r| r.as_array().is_some_and(|r| r.len() == 4)) => {
            rows.iter().flat_map(|r| r.as_array().into_iter().flatten()).collect()
        }
        Some(flat) if flat.len() == 16 => flat.iter().collect(),
        _ => Vec::new(),
    };
    let values: Vec<f64> = numbers.iter().filter_map(|v| v.as_f64()).filter(|v| v.is_finite()).collect();
    if numbers.len() != 16 || values.len() != 16 {
        return Err(format!("`{key}` must hold {expected} (a 4x4 matrix), it holds {}", Quoted(value)));
    }
    crate::input::pose_from_numbers(&values).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;

    #[test]
    fn a_frames_folder_reads_the_same_from_bytes_and_names_only_its_files() {
        let dir = std::env::temp_dir().join(format!("raypatch-frame-bytes-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("images")).unwrap();
        let pose = |x: f64| serde_json::json!([[1, 0, 0, x], [0, 0, -1, -6], [0, 1, 0, 1], [0, 0, 0, 1]]);
        let json = serde_json::json!({ "camera_angle_x": 0.8, "frames": [
            { "file_path": "./images/r_0", "transform_matrix": pose(0.0) },
            { "file_path": "images/r_1.png", "transform_matrix": pose(1.0) },
        ]})
        .to_string();
        let mut files = HashMap::new();
        for i in 0..2 {
            let png = Image::new(4, 2, vec![0.25 * i as f32; 24]).unwrap().encode_png().unwrap();
            std::fs::write(dir.join(format!("images/r_{i}.png")), &png).unwrap();
            files.insert(format!("images/r_{i}.png"), png);
        }
        std::fs::write(dir.join("transforms.json"), &json).unwrap();
        let on_disk = SceneData::from_frames(&dir).unwrap();
        let given = |name: &str| files.get(name).map(Vec::as_slice);
        let from_bytes = SceneData::from_frame_bytes("scene", json.as_bytes(), given).unwrap();
        assert_eq!(on_disk.inputs.len(), 2);
        for (a, b) in on_disk.inputs.iter().zip(&from_bytes.inputs) {
            assert_eq!(a.image.data(), b.image.data());
            assert_eq!(a.camera.as_pinhole(), b.camera.as_pinhole());
        }
        assert_eq!(on_disk.files.len(), 3);
        assert!(from_bytes.files.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();

        let with_name = |name: &str| {
            let json = serde_json::json!({ "camera_angle_x": 0.8,
                "frames": [{ "file_path": name, "transform_matrix": pose(0.0) }] });
            SceneData::from_frame_bytes("scene", json.to_string().as_bytes(), given).unwrap_err().to_string()
        };
        let error = with_name("../images/r_0.png");
        assert!(error.starts_with("scene/transforms.json: frame 0: `file_path`"), "{error}");
        assert!(error.contains("not a relative path inside the scene folder"), "{error}");
        assert!(with_name("images/r_2").contains("\"images/r_2.png\": no such file in the scene folder"));
        assert!(with_name("/images/r_0.png").contains("not a relative path"));
    }
}
