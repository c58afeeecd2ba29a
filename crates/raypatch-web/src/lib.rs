//! raypatch in the browser: the API crate (`raypatch`) on the visitor's GPU through WebGPU, bound to JavaScript
//! with wasm-bindgen (`.ci/web.sh` builds it and the page, `web/`). Models and scenes arrive as bytes (a file
//! picker, a drop, a fetch); every wait is a Promise; errors are exceptions whose message is the one line
//! `render-frame` prints for the same file or request.
//!
//! The engine holds its plans' locks across a render's awaits, and a browser has one thread: a second request
//! while one is running is refused (`busy`), never interleaved.

use std::cell::Cell;
use std::collections::HashMap;
use std::rc::Rc;

use raypatch::raypatch_model::error::one_line;
use raypatch::{EngineOptions, Output, Outputs, Request, SceneData, TargetView};
use wasm_bindgen::prelude::*;

/// An error as the page sees it: the message `render-frame` would print, on one line.
fn error(e: impl std::fmt::Display) -> JsError {
    JsError::new(&one_line(&e.to_string()))
}

/// Whether a request is running; shared by everything made from one [`Engine`].
#[derive(Clone, Default)]
struct Busy(Rc<Cell<bool>>);

/// Held while a request runs.
struct Running(Rc<Cell<bool>>);

impl Busy {
    fn start(&self, what: &str) -> Result<Running, JsError> {
        if self.0.replace(true) {
            return Err(JsError::new(&format!("{what}: the engine is busy with another request (await it first)")));
        }
        Ok(Running(self.0.clone()))
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.0.set(false);
    }
}

/// The browser's WebGPU adapter and device.
#[wasm_bindgen]
pub struct Engine {
    engine: Rc<raypatch::Engine>,
    busy: Busy,
}

#[wasm_bindgen]
impl Engine {
    /// The device on the browser's WebGPU adapter; an error where the browser has no WebGPU.
    pub async fn create() -> Result<Engine, JsError> {
        if !raypatch::raypatch_engine::wgpu::util::is_browser_webgpu_supported().await {
            return Err(JsError::new("this browser has no WebGPU (navigator.gpu gives no adapter)"));
        }
        let engine = raypatch::Engine::new_async(EngineOptions::default()).await.map_err(error)?;
        Ok(Engine { engine: Rc::new(engine), busy: Busy::default() })
    }

    /// The adapter: its name where the browser gives one, its kind (`Cpu` for a fallback adapter such as
    /// SwiftShader) and backend.
    #[wasm_bindgen(getter)]
    pub fn adapter(&self) -> String {
        let adapter = self.engine.adapter_details();
        let name = if adapter.name.is_empty() { "unnamed adapter" } else { &adapter.name };
        format!("{name} ({}, {})", adapter.kind, adapter.backend)
    }

    /// A model from the bytes of a model `.safetensors` or an official Lightning `.ckpt` (told apart by content);
    /// `name` names the file in errors.
    #[wasm_bindgen(js_name = loadModel)]
    pub fn load_model(&self, name: &str, bytes: &[u8]) -> Result<Model, JsError> {
        let _running = self.busy.start(name)?;
        let model = self.engine.load_bytes(name, bytes).map_err(error)?;
        Ok(Model { model: Rc::new(model), busy: self.busy.clone() })
    }
}

/// A model with its weights on the GPU.
#[wasm_bindgen]
pub struct Model {
    model: Rc<raypatch::Model>,
    busy: Busy,
}

#[wasm_bindgen]
impl Model {
    /// The model's name: "SRT", "OSRT", "DeFiNe", "RP-" before it for Ray-Patch models.
    #[wasm_bindgen(getter)]
    pub fn name(&self) -> String {
        self.model.config().name()
    }

    /// How it computes: its precision and the kernel family its GEMMs run on.
    #[wasm_bindgen(getter, js_name = computesAs)]
    pub fn computes_as(&self) -> String {
        self.model.computes_as()
    }

    /// The outputs it can render: `rgb`, and `logdepth`, `depth`, `segmentation` where the family has them.
    #[wasm_bindgen(getter)]
    pub fn outputs(&self) -> Vec<String> {
        self.model.outputs().iter().map(|o| o.name().to_string()).collect()
    }

    /// Pixels per decoded ray along each side (the Ray-Patch k; 1 otherwise): image sides must be multiples
    /// of it.
    #[wasm_bindgen(getter, js_name = patchSize)]
    pub fn patch_size(&self) -> usize {
        self.model.patch_size()
    }

    /// Encodes the scene's input views: the latent and what renders read, computed once.
    pub async fn encode(&self, scene: &SceneFile) -> Result<Scene, JsError> {
        let _running = self.busy.start(&scene.name)?;
        let model = self.model.clone();
        // SAFETY: `Scene` keeps `model` (this Rc) in the field after `scene`, so the model, whose heap place an Rc
        // never moves, outlives the encoded scene that borrows it, which is dropped first.
        let borrowed: &'static raypatch::Model = unsafe { &*Rc::as_ptr(&model) };
        let encoded = borrowed.encode_async(&scene.data.inputs).await.map_err(error)?;
        let inputs = scene.data.inputs.iter().map(|v| v.camera.clone()).collect();
        Ok(Scene { scene: encoded, inputs, targets: scene.data.targets.clone(), model, busy: self.busy.clone() })
    }
}

/// A scene file's posed views: inputs to encode, targets to render.
#[wasm_bindgen]
pub struct SceneFile {
    name: String,
    data: SceneData,
}

#[wasm_bindgen]
impl SceneFile {
    /// A scene from the bytes of a scene `.safetensors` file (docs/FORMATS.md); `name` names it in errors.
    #[wasm_bindgen(js_name = fromBytes)]
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<SceneFile, JsError> {
        Ok(SceneFile { name: name.to_string(), data: SceneData::from_bytes(name, bytes).map_err(error)? })
    }

    /// A scene from a frames folder's files (`transforms.json` and the images it names), as
    /// `render-frame --scene FOLDER` reads the folder on disk.
    #[wasm_bindgen(js_name = fromFolder)]
    pub fn from_folder(folder: &SceneFolder) -> Result<SceneFile, JsError> {
        let transforms = folder
            .files
            .get("transforms.json")
            .ok_or_else(|| JsError::new(&format!("{}: no transforms.json among the folder's files", folder.name)))?;
        let data =
            SceneData::from_frame_bytes(&folder.name, transforms, |name| folder.files.get(name).map(Vec::as_slice))
                .map_err(error)?;
        Ok(SceneFile { name: folder.name.clone(), data })
    }

    /// Input views.
    #[wasm_bindgen(getter, js_name = inputCount)]
    pub fn input_count(&self) -> usize {
        self.data.inputs.len()
    }

    /// Target views.
    #[wasm_bindgen(getter, js_name = targetCount)]
    pub fn target_count(&self) -> usize {
        self.data.targets.len()
    }
}

/// A frames folder's files by their names inside it (`transforms.json`, `images/r_0.png`, ...), gathered from
/// a folder pick or drop before [`SceneFile::from_folder`] reads them.
#[wasm_bindgen]
pub struct SceneFolder {
    name: String,
    files: HashMap<String, Vec<u8>>,
}

#[wasm_bindgen]
impl SceneFolder {
    /// An empty folder; `name` names it in errors (`name/transforms.json: ...`).
    #[wasm_bindgen(constructor)]
    pub fn new(name: &str) -> SceneFolder {
        SceneFolder { name: name.to_string(), files: HashMap::new() }
    }

    /// Adds the file at `path` inside the folder (parts joined by `/`).
    pub fn add(&mut self, path: &str, bytes: Vec<u8>) {
        self.files.insert(path.to_string(), bytes);
    }
}

fn target(targets: &[TargetView], view: usize) -> Result<&TargetView, JsError> {
    targets.get(view).ok_or_else(|| JsError::new(&format!("view {view}: the scene has {} target views", targets.len())))
}

/// A camera to render from.
#[wasm_bindgen]
pub struct Camera(raypatch::Camera);

#[wasm_bindgen]
impl Camera {
    /// A pinhole camera: `pose` the 4x4 camera-to-world matrix, 16 numbers row by row, in the OpenGL axes of a
    /// NeRF `transform_matrix` (x right, y up, looking along -z), and the intrinsics in pixels (`fl_x`, `fl_y`,
    /// `cx`, `cy`, `w`, `h` of `render-frame --pose`).
    pub fn pinhole(
        pose: &[f64],
        width: usize,
        height: usize,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
    ) -> Result<Camera, JsError> {
        camera_of(pose, raypatch::Intrinsics { width, height, fx, fy, cx, cy }).map(Camera).map_err(error)
    }
}

/// The page's camera input as the API's camera: the pose through the API's input module (the checks and messages
/// of every surface), in OpenGL axes as the page's orbit makes it.
fn camera_of(pose: &[f64], intrinsics: raypatch::Intrinsics) -> Result<raypatch::Camera, String> {
    let camera_to_world = raypatch::input::pose_from_numbers(pose).map_err(|e| e.to_string())?;
    raypatch::Camera::pinhole(intrinsics, camera_to_world, raypatch::CameraAxes::OpenGl).map_err(|e| e.to_string())
}

/// A scene encoded by a model.
#[wasm_bindgen]
pub struct Scene {
    /// Borrows `model` (see [`Model::encode`]): declared first, so dropped first.
    scene: raypatch::Scene<'static>,
    /// The input views' cameras (where the page orbits: [`orbit`](Self::orbit)).
    inputs: Vec<raypatch::Camera>,
    targets: Vec<TargetView>,
    model: Rc<raypatch::Model>,
    busy: Busy,
}

#[wasm_bindgen]
impl Scene {
    /// Renders `camera`: the `outputs` named (`rgb`, `logdepth`, `depth`, `segmentation`; empty: rgb).
    pub async fn render(&self, camera: &Camera, outputs: Vec<String>) -> Result<Rendered, JsError> {
        self.render_camera(&camera.0, &outputs, "render").await
    }

    /// Renders the scene's target view `view`, as `render-frame --view` does.
    #[wasm_bindgen(js_name = renderView)]
    pub async fn render_view(&self, view: usize, outputs: Vec<String>) -> Result<Rendered, JsError> {
        let camera = &target(&self.targets, view)?.camera;
        self.render_camera(camera, &outputs, &format!("view {view}")).await
    }

    /// Target view `view`'s camera as a pinhole camera (its own, or fitted to its rays): the camera-to-world pose,
    /// 16 numbers row by row in OpenGL axes as [`Camera::pinhole`] takes it, then `width, height, fx, fy, cx, cy`.
    #[wasm_bindgen(js_name = viewCamera)]
    pub fn view_camera(&self, view: usize) -> Result<Vec<f64>, JsError> {
        let camera = &target(&self.targets, view)?.camera;
        let (k, opencv) = raypatch::fit_pinhole(camera, self.model.ray_kind()).map_err(error)?;
        // The flip between the axis conventions is its own inverse.
        let opengl = raypatch::CameraAxes::OpenGl.to_opencv(opencv);
        let mut numbers = raypatch::input::pose_numbers(opengl).to_vec();
        numbers.extend([k.width as f64, k.height as f64, k.fx, k.fy, k.cx, k.cy]);
        Ok(numbers)
    }

    /// Where the page orbits: the point nearest every camera's optical axis (inputs and targets), then the world
    /// axis nearest the cameras' up directions.
    pub fn orbit(&self) -> Result<Vec<f64>, JsError> {
        let poses = self.poses()?;
        let centre = raypatch::scene_centre(&poses).map_err(error)?;
        Ok([centre.to_array(), raypatch::up_axis(&poses).to_array()].concat())
    }

    /// Frame `index` of `frames` of a motion preset (orbit, spiral, zoom, closeup, eyeroll) from target view 0,
    /// about the scene's centre: the camera `render-frame --motion NAME --frames N` renders as its frame
    /// `index`; at `width` x `height` (keeping the vertical field of view) where both are given.
    #[wasm_bindgen(js_name = motionCamera)]
    pub fn motion_camera(
        &self,
        motion: &str,
        frames: usize,
        index: usize,
        width: Option<usize>,
        height: Option<usize>,
    ) -> Result<Camera, JsError> {
        let preset = raypatch::Motion::from_name(motion).ok_or_else(|| {
            let known: Vec<&str> = raypatch::Motion::ALL.iter().map(|m| m.name()).collect();
            error(format!("motion `{motion}`: expected one of {}", known.join(", ")))
        })?;
        let size = match (width, height) {
            (Some(w), Some(h)) => Some((w, h)),
            (None, None) => None,
            _ => return Err(error(format!("motion {motion}: give both width and height, or neither"))),
        };
        let (k, pose) =
            raypatch::fit_pinhole(&target(&self.targets, 0)?.camera, self.model.ray_kind()).map_err(error)?;
        let k = raypatch::resized(k, size, None).map_err(error)?;
        let options = raypatch::MotionOptions::about(&self.poses()?, frames, None, None).map_err(error)?;
        let mut cameras = raypatch::motion_path(preset, (k, pose), &options).map_err(error)?;
        if index >= cameras.len() {
            return Err(error(format!("motion {motion}: frame {index}, the motion has {} frames", cameras.len())));
        }
        Ok(Camera(cameras.swap_remove(index)))
    }

    /// Every camera's pose (inputs and targets), fitted with a pinhole camera: what motions go about.
    fn poses(&self) -> Result<Vec<glam::DMat4>, JsError> {
        let cameras = self.inputs.iter().chain(self.targets.iter().map(|t| &t.camera));
        raypatch::fitted_poses(cameras, self.model.ray_kind()).map_err(error)
    }

    /// The outputs the model that encoded this scene can render.
    #[wasm_bindgen(getter)]
    pub fn outputs(&self) -> Vec<String> {
        self.model.outputs().iter().map(|o| o.name().to_string()).collect()
    }

    async fn render_camera(
        &self,
        camera: &raypatch::Camera,
        names: &[String],
        what: &str,
    ) -> Result<Rendered, JsError> {
        let _running = self.busy.start(what)?;
        let outputs = names
            .iter()
            .map(|name| {
                Output::from_name(name).ok_or_else(|| {
                    let known: Vec<&str> = Output::ALL.iter().map(|o| o.name()).collect();
                    error(format!("output `{name}`: expected one of {}", known.join(", ")))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let request = Request {
            outputs: if outputs.is_empty() { Outputs::default() } else { Outputs::of(&outputs) },
            ..Request::default()
        };
        let rendered = self.scene.render_async(camera, &request).await.map_err(error)?;
        Ok(Rendered { width: camera.width(), height: camera.height(), rendered })
    }
}

/// A render's outputs.
#[wasm_bindgen]
pub struct Rendered {
    width: usize,
    height: usize,
    rendered: raypatch::Rendered,
}

#[wasm_bindgen]
impl Rendered {
    #[wasm_bindgen(getter)]
    pub fn width(&self) -> usize {
        self.width
    }

    #[wasm_bindgen(getter)]
    pub fn height(&self) -> usize {
        self.height
    }

    /// The outputs rendered, by name.
    #[wasm_bindgen(getter)]
    pub fn outputs(&self) -> Vec<String> {
        self.rendered.outputs.iter().map(|o| o.output.name().to_string()).collect()
    }

    /// An output's values, `[height, width, channels]` row by row: what `render-frame --out-raw` writes.
    pub fn floats(&self, output: &str) -> Result<Vec<f32>, JsError> {
        Ok(self.output(output)?.to_vec())
    }

    /// An output as RGBA bytes for a canvas (`ImageData`): rgb as it is, depth (and log-depth, as depth)
    /// colour-mapped near red to far blue, segmentation each pixel in its most-weighted slot's colour.
    pub fn rgba(&self, output: &str) -> Result<Vec<u8>, JsError> {
        let (w, h) = (self.width, self.height);
        let image = match Output::from_name(output) {
            Some(Output::Rgb) => self.rendered.rgb(),
            Some(Output::Depth) => {
                self.rendered.depth().map(|d| raypatch::Image::from_depth(w, h, d, None)).transpose().map_err(error)?
            }
            Some(Output::LogDepth) => self
                .rendered
                .logdepth()
                .map(|l| raypatch::Image::from_depth(w, h, &l.iter().map(|v| v.exp()).collect::<Vec<_>>(), None))
                .transpose()
                .map_err(error)?,
            Some(Output::Segmentation) => self
                .rendered
                .segmentation()
                .map(|(weights, slots)| raypatch::Image::from_segmentation(w, h, weights, slots))
                .transpose()
                .map_err(error)?,
            None => None,
        };
        let image = image.ok_or_else(|| self.missing(output))?;
        Ok(image.to_rgb8().chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect())
    }

    fn output(&self, name: &str) -> Result<&[f32], JsError> {
        Output::from_name(name).and_then(|o| self.rendered.get(o)).ok_or_else(|| self.missing(name))
    }

    fn missing(&self, name: &str) -> JsError {
        JsError::new(&format!("output `{name}` was not rendered (rendered: {})", self.outputs().join(", ")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_camera_is_render_frames_pose_camera() {
        // A camera 6 units down -y looking at the origin, z up (the load_pose example of the API crate).
        let pose = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, -6.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let k = raypatch::Intrinsics { width: 32, height: 24, fx: 30.0, fy: 30.0, cx: 16.0, cy: 12.0 };
        let camera = camera_of(&pose, k).unwrap();
        assert_eq!(camera.position(), glam::DVec3::new(0.0, -6.0, 1.0));
        let (_, opencv) = camera.as_pinhole().unwrap();
        // OpenCV axes: looking along +z, which is world +y here.
        assert_eq!(opencv.z_axis.truncate(), glam::DVec3::new(0.0, 1.0, 0.0));
        assert!(camera_of(&pose[..15], k).unwrap_err().contains("pose: 15 numbers given"));
        let mut scaled = pose;
        scaled[0] = 2.0;
        assert!(camera_of(&scaled, k).unwrap_err().contains("not orthonormal"));
    }
}
