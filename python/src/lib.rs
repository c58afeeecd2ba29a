//! `raypatch._raypatch`: the engine's Rust API (the `raypatch` crate) for Python. Arrays cross as bytes
//! (little-endian f32 or u32, row-major) with their shapes beside them: the limited API of abi3 on
//! Python 3.9 has no buffer protocol, and `raypatch/__init__.py` turns numpy arrays into bytes and back. The
//! GIL is released while the engine works, so Python threads render at once. Errors and conversions:
//! `convert.rs`; cameras and their paths: `paths.rs`.

mod convert;
mod paths;
mod staging;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use glam::{DVec3, Vec3};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use raypatch::raypatch_model::error::{Quoted, MAX_QUOTED_CHARS};
use raypatch::{
    AdapterChoice, Camera, EngineOptions, Image, InputView, MatmulKernel, Precision, RayGrid, Request, SceneData,
};

use convert::{
    f32_bytes, f32s, image_of, image_sizes, input_error, outputs_of, region_of, to_py, u32s, unsigned, EngineClosed,
    Error, FileError, GpuError, InputError,
};

/// The bundled models (`assets/models`) by name, and the bundled scenes (`assets/scenes`).
const BUNDLED_MODELS: [(&str, &[u8]); 6] = [
    ("fitted", include_bytes!("../../assets/models/fitted_scene-2000000_rpsrt_k4.safetensors")),
    ("rpsrt_k2", include_bytes!("../../assets/models/rpsrt_k2.safetensors")),
    ("rpsrt_k4", include_bytes!("../../assets/models/rpsrt_k4.safetensors")),
    ("rpsrt_k8", include_bytes!("../../assets/models/rpsrt_k8.safetensors")),
    ("rpsrt_k8_long", include_bytes!("../../assets/models/rpsrt_k8_long.safetensors")),
    ("srt", include_bytes!("../../assets/models/srt.safetensors")),
];
const BUNDLED_SCENES: [(&str, &[u8]); 2] = [
    ("scene-2000000", include_bytes!("../../assets/scenes/scene-2000000.safetensors")),
    ("scene-2000001", include_bytes!("../../assets/scenes/scene-2000001.safetensors")),
];

/// Whether the engine was closed; shared by the engine and everything loaded on it.
#[derive(Clone, Default)]
struct Alive(Arc<AtomicBool>);

impl Alive {
    fn check(&self) -> PyResult<()> {
        if self.0.load(Ordering::Acquire) {
            return Err(EngineClosed::new_err("the engine was closed: create a new raypatch.Engine"));
        }
        Ok(())
    }
}

/// The engine: one GPU adapter (a real GPU when there is one, else lavapipe).
#[pyclass(frozen, module = "raypatch._raypatch")]
struct Engine {
    inner: Arc<raypatch::Engine>,
    alive: Alive,
}

#[pymethods]
impl Engine {
    #[new]
    #[pyo3(signature = (adapter=None, matmul=None, precision="f32"))]
    fn new(py: Python<'_>, adapter: Option<String>, matmul: Option<String>, precision: &str) -> PyResult<Engine> {
        let matmul = match matmul.as_deref() {
            None => None,
            Some(name) => Some(MatmulKernel::from_name(name).ok_or_else(|| {
                input_error(format!("matmul {:?}: expected \"rows\", \"tiled\" or \"lanes\"", Quoted(name)))
            })?),
        };
        let precision = Precision::from_name(precision).ok_or_else(|| {
            input_error(format!("precision {:?}: expected \"f32\", \"f16\" or \"f16-act\"", Quoted(precision)))
        })?;
        let adapter = adapter.map_or(AdapterChoice::Auto, AdapterChoice::NameContains);
        let options = EngineOptions { adapter, matmul, precision, ..Default::default() };
        let inner = py.detach(|| raypatch::Engine::new(options)).map_err(to_py)?;
        Ok(Engine { inner: Arc::new(inner), alive: Alive::default() })
    }

    /// Every adapter wgpu sees, the default first: dicts of name, kind, backend, driver.
    #[staticmethod]
    fn adapters(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
        raypatch::Engine::adapters()
            .into_iter()
            .map(|a| {
                let d = PyDict::new(py);
                d.set_item("name", a.name)?;
                d.set_item("kind", a.kind)?;
                d.set_item("backend", a.backend)?;
                d.set_item("driver", a.driver)?;
                Ok(d)
            })
            .collect()
    }

    #[getter]
    fn adapter(&self) -> String {
        self.inner.adapter()
    }

    #[getter]
    fn closed(&self) -> bool {
        self.alive.check().is_err()
    }

    /// Later calls on this engine and everything loaded on it raise EngineClosed.
    fn close(&self) {
        self.alive.0.store(true, Ordering::Release);
    }

    fn load(&self, py: Python<'_>, path: PathBuf) -> PyResult<Model> {
        self.alive.check()?;
        let model = py.detach(|| self.inner.load(&path)).map_err(to_py)?;
        Ok(Model { inner: Arc::new(model), alive: self.alive.clone() })
    }

    fn load_bundled(&self, py: Python<'_>, name: &str) -> PyResult<Model> {
        self.alive.check()?;
        let Some((_, bytes)) = BUNDLED_MODELS.iter().find(|(n, _)| *n == name) else {
            let names: Vec<&str> = BUNDLED_MODELS.iter().map(|(n, _)| *n).collect();
            return Err(input_error(format!("no bundled model {:?}: the bundled models are {names:?}", Quoted(name))));
        };
        let model = py.detach(|| self.inner.load_bytes(&format!("bundled model {name}"), bytes)).map_err(to_py)?;
        Ok(Model { inner: Arc::new(model), alive: self.alive.clone() })
    }
}

/// A model with its weights on the GPU.
#[pyclass(frozen, module = "raypatch._raypatch")]
struct Model {
    inner: Arc<raypatch::Model>,
    alive: Alive,
}

self_cell::self_cell!(
    /// An encoded scene with the model it borrows.
    struct EncodedCell {
        owner: Arc<raypatch::Model>,
        #[covariant]
        dependent: SceneOf,
    }
);
type SceneOf<'m> = raypatch::Scene<'m>;

impl Model {
    fn encode_views(&self, py: Python<'_>, views: Vec<InputView>) -> PyResult<Scene> {
        self.alive.check()?;
        let owner = self.inner.clone();
        let cell = py.detach(|| EncodedCell::try_new(owner, |model| model.encode(&views))).map_err(to_py)?;
        Ok(Scene { cell, alive: self.alive.clone() })
    }
}

#[pymethods]
impl Model {
    /// The resolved config (every key with the official defaults filled in), as JSON text.
    #[getter]
    fn config_json(&self) -> String {
        self.inner.config().raw.to_string()
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.config().label()
    }

    #[getter]
    fn path(&self) -> String {
        self.inner.path().to_string()
    }

    #[getter]
    fn patch_size(&self) -> usize {
        self.inner.patch_size()
    }

    #[getter]
    fn outputs(&self) -> Vec<&'static str> {
        self.inner.outputs().iter().map(|o| o.name()).collect()
    }

    #[getter]
    fn parameter_count(&self) -> usize {
        self.inner.parameter_count()
    }

    /// Encodes `count` images (`[count, height, width, 3]` f32 in [0, 1]) seen by pinhole cameras: row-major
    /// 4x4 camera-to-world poses with OpenCV axes (`paths::opencv_poses`) and `(fx, fy, cx, cy)` each.
    fn encode_posed(
        &self,
        py: Python<'_>,
        images: &[u8],
        shape: (i64, i64, i64),
        poses: Vec<[f64; 16]>,
        intrinsics: Vec<(f64, f64, f64, f64)>,
    ) -> PyResult<Scene> {
        let (count, width, height) = image_sizes("images", shape.0, shape.2, shape.1)?;
        let per = width * height * 3;
        if poses.len() != count || intrinsics.len() != count {
            return Err(input_error(format!(
                "{count} images with {} poses and {} intrinsics: expected one of each per image",
                poses.len(),
                intrinsics.len()
            )));
        }
        let values = f32s("images", images, count * per)?;
        let views = (0..count)
            .map(|i| {
                let image = Image::new(width, height, values[i * per..(i + 1) * per].to_vec()).map_err(to_py)?;
                let (fx, fy, cx, cy) = intrinsics[i];
                let (width, height) = (width as i64, height as i64);
                let camera = paths::camera_of((poses[i], (fx, fy, cx, cy, width, height)))
                    .map_err(|e| input_error(format!("view {i}: {}", e.value(py))))?;
                Ok(InputView { image, camera })
            })
            .collect::<PyResult<Vec<_>>>()?;
        self.encode_views(py, views)
    }

    /// Encodes images with explicit rays: camera centres `[count, 3]` and rays `[count, height, width, 3]`
    /// (of the model's kind: unit directions, or unit-depth points for DeFiNe), as scene files hold them.
    fn encode_rays(
        &self,
        py: Python<'_>,
        images: &[u8],
        shape: (i64, i64, i64),
        positions: Vec<[f64; 3]>,
        rays: &[u8],
    ) -> PyResult<Scene> {
        let (count, width, height) = image_sizes("images", shape.0, shape.2, shape.1)?;
        let per = width * height * 3;
        if positions.len() != count {
            return Err(input_error(format!("{count} images with {} camera positions", positions.len())));
        }
        let values = f32s("images", images, count * per)?;
        let rays = f32s("rays", rays, count * per)?;
        let views = (0..count)
            .map(|i| {
                let image = Image::new(width, height, values[i * per..(i + 1) * per].to_vec()).map_err(to_py)?;
                let grid = RayGrid {
                    width,
                    height,
                    rays: rays[i * per..(i + 1) * per].chunks_exact(3).map(Vec3::from_slice).collect(),
                };
                let camera = Camera::from_rays(DVec3::from_array(positions[i]), grid)
                    .map_err(|e| input_error(format!("view {i}: {e}")))?;
                Ok(InputView { image, camera })
            })
            .collect::<PyResult<Vec<_>>>()?;
        self.encode_views(py, views)
    }

    /// Encodes the input views of a scene file or frames folder.
    fn encode_data(&self, py: Python<'_>, data: &SceneFile) -> PyResult<Scene> {
        self.encode_views(py, data.inner.inputs.clone())
    }
}

/// Posed views read from a scene file or a `transforms.json` folder.
#[pyclass(frozen, name = "SceneData", module = "raypatch._raypatch")]
struct SceneFile {
    inner: SceneData,
}

#[pymethods]
impl SceneFile {
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<SceneFile> {
        Ok(SceneFile { inner: py.detach(|| SceneData::load(&path)).map_err(to_py)? })
    }

    #[staticmethod]
    fn bundled(name: &str) -> PyResult<SceneFile> {
        let Some((_, bytes)) = BUNDLED_SCENES.iter().find(|(n, _)| *n == name) else {
            let names: Vec<&str> = BUNDLED_SCENES.iter().map(|(n, _)| *n).collect();
            return Err(input_error(format!("no bundled scene {:?}: the bundled scenes are {names:?}", Quoted(name))));
        };
        Ok(SceneFile { inner: SceneData::from_bytes(&format!("bundled scene {name}"), bytes).map_err(to_py)? })
    }

    #[getter]
    fn input_count(&self) -> usize {
        self.inner.inputs.len()
    }

    #[getter]
    fn target_count(&self) -> usize {
        self.inner.targets.len()
    }

    /// `(width, height)` of target view `i`.
    fn target_size(&self, i: i64) -> PyResult<(usize, usize)> {
        let t = self.target(i)?;
        Ok((t.camera.width(), t.camera.height()))
    }

    /// Target view `i`'s ground truth `[height, width, 3]` f32, or None.
    fn target_image<'py>(&self, py: Python<'py>, i: i64) -> PyResult<Option<Bound<'py, PyBytes>>> {
        Ok(self.target(i)?.image.as_ref().map(|im| f32_bytes(py, im.data())))
    }

    /// Target view `i`'s object ids `[height, width]` u32 (0: background), or None.
    fn target_masks<'py>(&self, py: Python<'py>, i: i64) -> PyResult<Option<Bound<'py, PyBytes>>> {
        let masks = self.target(i)?.masks.as_ref();
        Ok(masks.map(|m| PyBytes::new(py, &m.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>())))
    }

    /// Target view `i`'s depth `[height, width]` f32 in metres (0: none), or None.
    fn target_depth<'py>(&self, py: Python<'py>, i: i64) -> PyResult<Option<Bound<'py, PyBytes>>> {
        Ok(self.target(i)?.depth.as_ref().map(|d| f32_bytes(py, d)))
    }
}

impl SceneFile {
    fn target(&self, i: i64) -> PyResult<&raypatch::TargetView> {
        let i = unsigned("target view", i)?;
        self.inner.targets.get(i).ok_or_else(|| {
            input_error(format!(
                "target view {i}: the scene has {} (0..{})",
                self.inner.targets.len(),
                self.inner.targets.len()
            ))
        })
    }
}

/// An encoded scene: render it from any camera.
#[pyclass(frozen, module = "raypatch._raypatch")]
struct Scene {
    cell: EncodedCell,
    alive: Alive,
}

impl Scene {
    fn dict<'py>(py: Python<'py>, rendered: &raypatch::Rendered) -> PyResult<Bound<'py, PyDict>> {
        let result = PyDict::new(py);
        for out in &rendered.outputs {
            let shape = (rendered.region.height, rendered.region.width, out.channels);
            result.set_item(out.output.name(), (f32_bytes(py, &out.values), shape))?;
        }
        Ok(result)
    }

    fn render_camera<'py>(
        &self,
        py: Python<'py>,
        camera: &Camera,
        outputs: Vec<String>,
        region: Option<(i64, i64, i64, i64)>,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.alive.check()?;
        let request = Request { outputs: outputs_of(outputs)?, region: region_of(region)? };
        let rendered = py.detach(|| self.cell.borrow_dependent().render(camera, &request)).map_err(to_py)?;
        Scene::dict(py, &rendered)
    }
}

#[pymethods]
impl Scene {
    /// Renders a pinhole camera (see paths.rs): `{output name: (bytes of f32, (height, width, channels))}`
    /// over the region (x, y, width, height).
    #[pyo3(signature = (camera, outputs, region=None))]
    fn render_posed<'py>(
        &self,
        py: Python<'py>,
        camera: paths::Pinhole,
        outputs: Vec<String>,
        region: Option<(i64, i64, i64, i64)>,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.render_camera(py, &paths::camera_of(camera)?, outputs, region)
    }

    /// Renders pinhole cameras of one size (OpenCV poses, see paths.rs), one dict each (as `render_posed`):
    /// `batch` views per render call (None: as many as the memory budget allows), each batch submitted before
    /// the last is read back (raypatch's `Scene::render_path`).
    #[pyo3(signature = (cameras, outputs, region=None, batch=None))]
    fn render_batch<'py>(
        &self,
        py: Python<'py>,
        cameras: Vec<paths::Pinhole>,
        outputs: Vec<String>,
        region: Option<(i64, i64, i64, i64)>,
        batch: Option<i64>,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.alive.check()?;
        let cameras = cameras.into_iter().map(paths::camera_of).collect::<PyResult<Vec<_>>>()?;
        let request = Request { outputs: outputs_of(outputs)?, region: region_of(region)? };
        let batch = batch.map(|b| unsigned("batch", b)).transpose()?;
        let scene = self.cell.borrow_dependent();
        let frames = py
            .detach(|| match batch {
                Some(batch) => scene.render_path(&cameras, &request, batch).collect(),
                None => scene.render_batch(&cameras, &request),
            })
            .map_err(to_py)?;
        frames.iter().map(|f| Scene::dict(py, f)).collect()
    }

    /// A scene file's cameras, inputs then targets, as pinhole cameras (OpenCV poses; cameras given as rays
    /// fitted with one, see raypatch::fit_pinhole).
    fn fitted_cameras(&self, data: &SceneFile) -> PyResult<Vec<paths::Pinhole>> {
        let kind = self.cell.borrow_owner().ray_kind();
        let cameras = (data.inner.inputs.iter().map(|v| &v.camera)).chain(data.inner.targets.iter().map(|t| &t.camera));
        cameras.map(|c| raypatch::fit_pinhole(c, kind).map(paths::to_tuple).map_err(to_py)).collect()
    }

    /// Renders target view `i` of a scene file or frames folder (as `render_posed`).
    #[pyo3(signature = (data, i, outputs, region=None))]
    fn render_target<'py>(
        &self,
        py: Python<'py>,
        data: &SceneFile,
        i: i64,
        outputs: Vec<String>,
        region: Option<(i64, i64, i64, i64)>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let camera = data.target(i)?.camera.clone();
        self.render_camera(py, &camera, outputs, region)
    }
}

/// PSNR in dB of two `[height, width, 3]` f32 images.
#[pyfunction]
fn psnr(py: Python<'_>, a: &[u8], b: &[u8], width: i64, height: i64) -> PyResult<f64> {
    let (a, b) = (image_of("a", a, width, height)?, image_of("b", b, width, height)?);
    py.detach(|| raypatch::metrics::psnr(&a, &b)).map_err(to_py)
}

/// SSIM of two `[height, width, 3]` f32 images (the official evaluation's).
#[pyfunction]
fn ssim(py: Python<'_>, a: &[u8], b: &[u8], width: i64, height: i64) -> PyResult<f64> {
    let (a, b) = (image_of("a", a, width, height)?, image_of("b", b, width, height)?);
    py.detach(|| raypatch::metrics::ssim(&a, &b)).map_err(to_py)
}

/// FG-ARI of slot weights `[pixels, slots]` f32 against object ids `[pixels]` u32 (0: background).
#[pyfunction]
fn fg_ari(true_ids: &[u8], weights: &[u8], pixels: i64, slots: i64) -> PyResult<f64> {
    let (pixels, slots) = (unsigned("pixels", pixels)?, unsigned("slots", slots)?);
    let ids = u32s("true_ids", true_ids, pixels)?;
    let values = pixels.checked_mul(slots).ok_or_else(|| input_error(format!("weights: {pixels} x {slots} values")))?;
    let weights = f32s("weights", weights, values)?;
    raypatch::metrics::fg_ari(&ids, &weights, slots).map_err(to_py)
}

/// Abs.Rel, Sq.Rel, RMSE and the pixel count of predicted depth against ground truth (`[pixels]` f32 each).
#[pyfunction]
fn depth_errors(predicted: &[u8], truth: &[u8], pixels: i64) -> PyResult<(f64, f64, f64, usize)> {
    let pixels = unsigned("pixels", pixels)?;
    let e = raypatch::metrics::depth_errors(&f32s("predicted", predicted, pixels)?, &f32s("truth", truth, pixels)?)
        .map_err(to_py)?;
    Ok((e.abs_rel, e.sq_rel, e.rmse, e.pixels))
}

/// [`image_sizes`] for the package, to check arrays before converting them.
#[pyfunction]
fn check_images(what: &str, count: i64, width: i64, height: i64) -> PyResult<()> {
    image_sizes(what, count, width, height).map(|_| ())
}

/// Writes a `[height, width, 3]` f32 image in [0, 1] as a PNG (written beside, then renamed into place).
#[pyfunction]
fn save_png(py: Python<'_>, rgb: &[u8], width: i64, height: i64, path: PathBuf) -> PyResult<()> {
    let image = image_of("rgb", rgb, width, height)?;
    py.detach(|| image.save_png(&path)).map_err(to_py)
}

/// The variables that put Mesa's shader cache where it can be written, or turn it off, and a note saying so
/// (None: nothing to change): the package sets them through `os.environ` when imported, before any engine
/// loads a driver (issue 50). Computed here, set by Python: setting the environment from Rust while other
/// threads may read it would not be sound.
#[pyfunction]
fn driver_cache_env() -> (Vec<(String, std::ffi::OsString)>, Option<String>) {
    let (vars, note) = raypatch::raypatch_engine::pipeline_cache::mesa_cache_env();
    (vars.into_iter().map(|(name, value)| (name.to_string(), value)).collect(), note)
}

#[pymodule]
fn _raypatch(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    m.add("GpuError", py.get_type::<GpuError>())?;
    m.add("EngineClosed", py.get_type::<EngineClosed>())?;
    m.add("BUNDLED_MODELS", BUNDLED_MODELS.iter().map(|(n, _)| *n).collect::<Vec<_>>())?;
    m.add("BUNDLED_SCENES", BUNDLED_SCENES.iter().map(|(n, _)| *n).collect::<Vec<_>>())?;
    // The engine's limits, for the package to check arrays against before converting them.
    m.add("MAX_SCENE_PIXELS", raypatch::MAX_SCENE_PIXELS)?;
    // How much of a value a message quotes, for the package's own messages to quote alike.
    m.add("MAX_QUOTED_CHARS", MAX_QUOTED_CHARS)?;
    m.add_class::<Engine>()?;
    m.add_class::<Model>()?;
    m.add_class::<SceneFile>()?;
    m.add_class::<Scene>()?;
    m.add_function(wrap_pyfunction!(driver_cache_env, m)?)?;
    m.add_function(wrap_pyfunction!(psnr, m)?)?;
    m.add_function(wrap_pyfunction!(ssim, m)?)?;
    m.add_function(wrap_pyfunction!(fg_ari, m)?)?;
    m.add_function(wrap_pyfunction!(depth_errors, m)?)?;
    m.add_function(wrap_pyfunction!(save_png, m)?)?;
    m.add_function(wrap_pyfunction!(check_images, m)?)?;
    m.add_function(wrap_pyfunction!(paths::motion_cameras, m)?)?;
    m.add_function(wrap_pyfunction!(paths::interpolate_cameras, m)?)?;
    m.add_function(wrap_pyfunction!(paths::scene_centre, m)?)?;
    m.add_function(wrap_pyfunction!(paths::up_axis, m)?)?;
    m.add_function(wrap_pyfunction!(paths::camera_path_cameras, m)?)?;
    m.add_class::<staging::Staged>()?;
    m.add("TEMP_MARK", raypatch::TEMP_MARK)?;
    m.add("MAX_NAME_BYTES", raypatch::MAX_NAME_BYTES)?;
    m.add("STOP_SECONDS", raypatch::STOP_SECONDS)?;
    m.add_function(wrap_pyfunction!(staging::check_outputs, m)?)?;
    m.add_function(wrap_pyfunction!(staging::sibling, m)?)?;
    m.add_function(wrap_pyfunction!(staging::encode_png, m)?)?;
    m.add_function(wrap_pyfunction!(staging::stop_on_signals, m)?)?;
    m.add_function(wrap_pyfunction!(staging::stop, m)?)?;
    m.add_function(wrap_pyfunction!(paths::opencv_poses, m)?)?;
    m.add_function(wrap_pyfunction!(paths::resized_camera, m)?)?;
    Ok(())
}
