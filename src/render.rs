//! The engine, models, encoded scenes and renders.

use std::path::Path;
use std::sync::Arc;

use raypatch_engine::encoded::BATCH_BUDGET_BYTES;
use raypatch_engine::{
    AdapterChoice, EncodedScene, Gpu, GpuOptions, LoadOptions, MatmulKernel, Output, Outputs, PipelineCacheDir,
    PipelineCacheStatus, Precision, RenderStats, Request,
};
use raypatch_model::{InputViews, ModelConfig, RayKind};

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::Region;

// Paths of renders are blocking iterators: native only (a browser renders a camera at a time, awaited).
#[cfg(not(target_family = "wasm"))]
mod path;
#[cfg(not(target_family = "wasm"))]
use path::Batches;
#[cfg(not(target_family = "wasm"))]
pub use path::RenderPath;

/// How to set up the [`Engine`].
///
/// ```
/// use raypatch::{AdapterChoice, EngineOptions};
/// let on_lavapipe = EngineOptions { adapter: AdapterChoice::NameContains("llvmpipe".into()), ..Default::default() };
/// assert!(matches!(EngineOptions::default().adapter, AdapterChoice::Auto));
/// # let _ = on_lavapipe;
/// ```
#[derive(Clone, Debug, Default)]
pub struct EngineOptions {
    /// Which adapter to run on: by default a real GPU when there is one, else a CPU one such as lavapipe.
    pub adapter: AdapterChoice,
    /// The largest GPU buffer the engine may use, in bytes, when below the adapter's own limit (`None`: the
    /// adapter's limit). Renders that would need larger buffers run in row bands (the same pixels, up to f32 rounding on GPUs).
    pub max_buffer_bytes: Option<u64>,
    /// The kernel linear layers run on (`None`: the adapter's fastest; `Some` to compare or check one).
    pub matmul: Option<MatmulKernel>,
    /// The precision models load at: f32 (the default), f16 linear weights, or f16 weights and activations
    /// (faster on GPUs with shader-f16, rgb within ~1e-2; see [`Precision`]). f16 needs the adapter's shader-f16.
    pub precision: Precision,
    /// Where compiled GPU pipelines are kept between runs (Vulkan): by default `$RAYPATCH_CACHE_DIR` (`off`
    /// turns it off), else `$XDG_CACHE_HOME/raypatch`, else `$HOME/.cache/raypatch`.
    pub pipeline_cache: PipelineCacheDir,
}

/// A GPU adapter wgpu can see.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Adapter {
    /// The device's name, as `--adapter` matches it.
    pub name: String,
    /// `DiscreteGpu`, `IntegratedGpu`, `VirtualGpu`, `Cpu` or `Other`.
    pub kind: String,
    /// `Vulkan`, `Metal`, `Dx12` or `Gl`.
    pub backend: String,
    /// Driver name and version.
    pub driver: String,
}

impl Adapter {
    fn from_info(info: &raypatch_engine::wgpu::AdapterInfo) -> Adapter {
        Adapter {
            name: info.name.clone(),
            kind: format!("{:?}", info.device_type),
            backend: format!("{:?}", info.backend),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        }
    }

    /// Whether this is a real GPU: a discrete, integrated or virtual one, not a CPU rasteriser such as
    /// lavapipe or llvmpipe, and not reached through OpenGL (wgpu's fallback when no Vulkan, Metal or DX12
    /// driver is found).
    pub fn is_gpu(&self) -> bool {
        matches!(self.kind.as_str(), "DiscreteGpu" | "IntegratedGpu" | "VirtualGpu") && self.backend != "Gl"
    }
}

impl std::fmt::Display for Adapter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}, {}, {})", self.name, self.kind, self.backend, self.driver)
    }
}

/// The GPU context: an adapter, its device, and the compiled kernels, shared by every model loaded on it.
///
/// ```
/// use raypatch::{Engine, EngineOptions};
/// let engine = Engine::new(EngineOptions::default())?;
/// println!("rendering on {}", engine.adapter());
/// # Ok::<(), raypatch::Error>(())
/// ```
pub struct Engine {
    gpu: Arc<Gpu>,
    load: LoadOptions,
}

impl Engine {
    /// Opens the adapter the options ask for.
    #[cfg(not(target_family = "wasm"))]
    pub fn new(options: EngineOptions) -> Result<Engine> {
        pollster::block_on(Engine::new_async(options))
    }

    /// Opens the adapter the options ask for (in a browser, its WebGPU adapter), once the device is made.
    pub async fn new_async(options: EngineOptions) -> Result<Engine> {
        Ok(Engine {
            gpu: Arc::new(
                Gpu::new_async(&GpuOptions {
                    adapter: options.adapter,
                    max_buffer_bytes: options.max_buffer_bytes,
                    matmul: options.matmul,
                    pipeline_cache: options.pipeline_cache,
                    without_subgroups: false,
                    rays_on_host: false,
                })
                .await?,
            ),
            load: LoadOptions { precision: options.precision },
        })
    }

    /// Every adapter wgpu can see that runs compute shaders, in the order [`AdapterChoice::Auto`] prefers
    /// them: the first is the default.
    ///
    /// ```
    /// for adapter in raypatch::Engine::adapters() {
    ///     println!("{adapter}");
    /// }
    /// ```
    #[cfg(not(target_family = "wasm"))]
    pub fn adapters() -> Vec<Adapter> {
        raypatch_engine::gpu::list_adapters().iter().map(Adapter::from_info).collect()
    }

    /// The adapter in use, as "name (backend, driver)".
    pub fn adapter(&self) -> String {
        self.gpu.describe()
    }

    /// The adapter in use, in detail.
    pub fn adapter_details(&self) -> Adapter {
        Adapter::from_info(&self.gpu.info)
    }

    /// Loads a model file (safetensors with the official key names and the config in its metadata, see
    /// docs/FORMATS.md, or an official Lightning `.ckpt` checkpoint, told apart by content) and uploads its
    /// weights. Every tensor is checked by name, shape and dtype.
    ///
    /// ```
    /// # let engine = raypatch::Engine::new(Default::default())?;
    /// let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k4");
    /// let model = engine.load(format!("{golden}/model.safetensors"))?;
    /// assert_eq!(model.patch_size(), 4);
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn load(&self, path: impl AsRef<Path>) -> Result<Model> {
        let loaded = raypatch_model::load_model(path)?;
        Ok(Model { inner: raypatch_engine::Model::from_loaded_with(self.gpu.clone(), &loaded, &self.load)? })
    }

    /// Loads a model from the bytes of a model file (e.g. one embedded in a program); `name` stands for the
    /// file in messages.
    pub fn load_bytes(&self, name: &str, bytes: &[u8]) -> Result<Model> {
        let loaded = raypatch_model::weights::model_from_bytes(name, bytes)?;
        Ok(Model { inner: raypatch_engine::Model::from_loaded_with(self.gpu.clone(), &loaded, &self.load)? })
    }

    /// What the GPU has done so far (pipelines compiled, buffers created, submits, dispatches): for checking
    /// that work is skipped or reused.
    pub fn counters(&self) -> raypatch_engine::gpu::CounterSnapshot {
        self.gpu.counters()
    }

    /// The file compiled pipelines are kept in between runs, or why there is none (the backend has no
    /// pipeline cache, or it is turned off). It is written when the engine and everything loaded on it are
    /// dropped, or by [`save_pipeline_cache`](Self::save_pipeline_cache). The time spent compiling is
    /// [`counters`](Self::counters)`().pipeline_compile_nanos`.
    pub fn pipeline_cache(&self) -> PipelineCacheStatus {
        self.gpu.pipeline_cache_status()
    }

    /// Writes the pipeline cache now if pipelines were compiled since it was last written; whether it wrote.
    pub fn save_pipeline_cache(&self) -> Result<bool> {
        self.gpu.save_pipeline_cache().map_err(|source| Error::Io {
            path: match self.pipeline_cache() {
                PipelineCacheStatus::File { path, .. } => path.display().to_string(),
                PipelineCacheStatus::Unavailable(_) => "pipeline cache".into(),
            },
            action: "cannot write",
            source,
        })
    }
}

/// A model with its weights on the GPU.
pub struct Model {
    inner: raypatch_engine::Model,
}

/// A posed input image.
#[derive(Clone, Debug)]
pub struct InputView {
    /// RGB in [0, 1].
    pub image: Image,
    /// A camera of the image's size, with one ray per pixel.
    pub camera: Camera,
}

impl Model {
    /// The resolved config (every dimension, with the official defaults filled in).
    pub fn config(&self) -> &ModelConfig {
        &self.inner.config
    }

    /// The file the model was loaded from.
    pub fn path(&self) -> &str {
        &self.inner.path
    }

    /// Ray-Patch's k (pixels per patch side); 1 for SRT.
    pub fn patch_size(&self) -> usize {
        self.inner.config.patch_size()
    }

    /// The image sizes the model renders (see [`crate::input::check_patch_size`]).
    pub fn target_sizes(&self) -> crate::input::PatchSize {
        crate::input::PatchSize::of(&self.inner.config)
    }

    /// What the model's rays are: unit directions (SRT, OSRT) or unit-depth points (DeFiNe). Cameras given by
    /// rays must hold this kind; pinhole cameras are turned into it.
    pub fn ray_kind(&self) -> RayKind {
        self.inner.config.ray_kind()
    }

    /// Whether the model predicts log-depth (4 output channels).
    pub fn has_depth(&self) -> bool {
        self.inner.outputs().contains(Output::LogDepth)
    }

    /// The outputs this model renders (see [`Output`]).
    pub fn outputs(&self) -> Outputs {
        self.inner.outputs()
    }

    /// Number of parameters in the file (BatchNorm statistics included).
    pub fn parameter_count(&self) -> usize {
        self.inner.parameter_count
    }

    /// Bytes of GPU memory the weights take.
    pub fn weight_bytes(&self) -> u64 {
        self.inner.weight_bytes()
    }

    /// Its precision and the kernel family its GEMMs run on (the tensor kernels under f16-act where the device has
    /// them; where not, why): what `render-frame --timings` prints.
    pub fn computes_as(&self) -> String {
        self.inner.computes_as()
    }

    /// Encodes posed input images into a [`Scene`]: the latent tokens and each decoder layer's keys and
    /// values, computed once and kept for every render. All views must have the same size (any size: each
    /// conv block halves it, rounding up, as in PyTorch), values in [0, 1], and cameras of that size with one
    /// ray per pixel.
    ///
    /// ```
    /// # let engine = raypatch::Engine::new(Default::default())?;
    /// let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k4");
    /// let model = engine.load(format!("{golden}/model.safetensors"))?;
    /// let data = raypatch::SceneData::load(format!("{golden}/scene.safetensors"))?;
    /// let scene = model.encode(&data.inputs)?;
    /// assert!(model.encode(&[]).is_err());
    /// # let _ = scene;
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    #[cfg(not(target_family = "wasm"))]
    pub fn encode(&self, views: &[InputView]) -> Result<Scene<'_>> {
        pollster::block_on(self.encode_async(views))
    }

    /// [`encode`](Self::encode), ready once the GPU is done (the one a browser has).
    pub async fn encode_async(&self, views: &[InputView]) -> Result<Scene<'_>> {
        self.check_inputs(views)?;
        Ok(Scene { inner: self.inner.encode_async(&input_views(views, self.ray_kind())?).await? })
    }

    /// Checks input views against what this model takes (see [`check_camera`](Self::check_camera)); returns
    /// the warnings.
    pub fn check_inputs(&self, views: &[InputView]) -> Result<Vec<String>> {
        let mut warnings = Vec::new();
        for (i, view) in views.iter().enumerate() {
            let octaves = self.config().position_octaves().0;
            warnings.extend(check_camera(&view.camera, self.ray_kind(), octaves, &format!("input view {i}"))?);
        }
        Ok(warnings)
    }

    /// Checks a target camera against what this model takes: an error for what its contract rules out (given
    /// rays that are not of the model's [`RayKind`], see [`Camera::check_rays`]; a camera so far out that the
    /// positional encoding keeps no phase in float32), warnings for legal values beyond the range where the
    /// engine matches PyTorch to float32 rounding.
    pub fn check_camera(&self, camera: &Camera) -> Result<Vec<String>> {
        check_camera(camera, self.ray_kind(), self.config().position_octaves().1, "target camera")
    }

    /// Encodes like [`encode`](Self::encode), op by op, and returns each op's label and time (for profiling).
    #[cfg(not(target_family = "wasm"))]
    pub fn profile_encode(&self, views: &[InputView]) -> Result<raypatch_engine::OpTimes> {
        Ok(self.inner.encode_profiled(&input_views(views, self.ray_kind())?)?.1)
    }
}

/// Positional-encoding arguments (coordinate times multiplier) beyond this keep no phase in float32 (its
/// spacing there is 2 radians): the model cannot see where the camera is.
const MAX_ENCODING_ARGUMENT: f64 = (1u64 << 24) as f64;
/// Up to this the engine's sine and cosine match PyTorch's to float32 rounding (`shaders/posenc.wgsl`).
const ACCURATE_ENCODING_ARGUMENT: f64 = (1u64 << 20) as f64;

fn check_camera(camera: &Camera, kind: RayKind, octaves: &raypatch_model::Octaves, what: &str) -> Result<Vec<String>> {
    // Only given rays need looking at: a pinhole camera's are of the model's kind by construction (and
    // computing them here would do a render's ray work twice).
    camera.check_rays(kind).map_err(|reason| Error::Camera(format!("{what}: {reason}")))?;
    let top = octaves.max_multiplier();
    let position = camera.position();
    let argument = position.abs().max_element() * top;
    if argument > MAX_ENCODING_ARGUMENT {
        return Err(Error::Camera(format!(
            "{what}: camera position {position} times the largest positional-encoding multiplier ({top:.1}) is \
             {argument:.3e}, beyond 2^24 where float32 keeps no phase: the model cannot encode this camera"
        )));
    }
    let mut warnings = Vec::new();
    if argument > ACCURATE_ENCODING_ARGUMENT {
        warnings.push(format!(
            "{what}: camera position {position} is far out for this model (positional-encoding argument \
             {argument:.3e} > 2^20): the render may differ from PyTorch's beyond float32 rounding"
        ));
    }
    Ok(warnings)
}

fn input_views(views: &[InputView], kind: RayKind) -> Result<InputViews> {
    let first = views.first().ok_or_else(|| Error::Views("no input view: a scene needs at least one".into()))?;
    let (width, height) = (first.image.width(), first.image.height());
    let mut inputs = InputViews {
        count: views.len(),
        height,
        width,
        images: Vec::with_capacity(views.len() * width * height * 3),
        camera_pos: Vec::with_capacity(views.len() * 3),
        rays: Vec::with_capacity(views.len() * width * height * 3),
    };
    for (i, view) in views.iter().enumerate() {
        let (image, camera) = (&view.image, &view.camera);
        if (image.width(), image.height()) != (width, height) {
            return Err(Error::Views(format!(
                "view {i} is {}x{}, view 0 is {width}x{height}: all input views must have the same size",
                image.width(),
                image.height()
            )));
        }
        if (camera.width(), camera.height()) != (width, height) || camera.pixels_per_ray() != 1 {
            return Err(Error::Views(format!(
                "view {i}: the camera is for a {}x{} image with one ray per {} pixel(s), the image is {width}x{height}",
                camera.width(),
                camera.height(),
                camera.pixels_per_ray()
            )));
        }
        if let Some(v) = image.data().iter().position(|v| !(0.0..=1.0).contains(v)) {
            return Err(Error::Views(format!("view {i}: value {v} is {}, expected [0, 1]", image.data()[v])));
        }
        inputs.images.extend_from_slice(image.data());
        inputs.camera_pos.extend(camera.position().as_vec3().to_array());
        inputs.rays.extend(camera.rays_of(kind).rays.iter().flat_map(|d| d.to_array()));
    }
    Ok(inputs)
}

/// A scene encoded by a model, rendered from any camera.
pub struct Scene<'m> {
    inner: EncodedScene<'m>,
}

/// The outputs of one render, over the requested region.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// Where the pixels lie in the camera's image.
    pub region: Region,
    /// The requested outputs, each `[height, width, channels]` row-major over the region.
    pub outputs: Vec<raypatch_engine::OutputValues>,
}

impl Rendered {
    /// The values of `output`, `[height, width, channels]`, when it was requested.
    pub fn get(&self, output: Output) -> Option<&[f32]> {
        self.outputs.iter().find(|r| r.output == output).map(|r| r.values.as_slice())
    }

    /// The colour image, when requested.
    pub fn rgb(&self) -> Option<Image> {
        let values = self.get(Output::Rgb)?.to_vec();
        Some(Image::new(self.region.width, self.region.height, values).expect("a frame's rgb has its region's size"))
    }

    /// Log-depth, `[height, width]` row-major, when requested.
    pub fn logdepth(&self) -> Option<&[f32]> {
        self.get(Output::LogDepth)
    }

    /// Depth = exp(log-depth) in the scene's unit (metres for ScanNet), `[height, width]` row-major, when
    /// requested ([`Image::from_depth`] colours it, [`crate::metrics::depth_errors`] scores it).
    pub fn depth(&self) -> Option<&[f32]> {
        self.get(Output::Depth)
    }

    /// The slot weights of an OSRT model, `[height, width, slots]` row-major, with the slot count, when
    /// requested.
    pub fn segmentation(&self) -> Option<(&[f32], usize)> {
        let r = self.outputs.iter().find(|r| r.output == Output::Segmentation)?;
        Some((r.values.as_slice(), r.channels))
    }
}

impl<'m> Scene<'m> {
    /// Renders the view of `camera`: the outputs the request asks for, over its region (the whole image by
    /// default). The first render of a size builds a plan; later renders of that size (any camera, any
    /// region position of the same computed size) reuse it with no allocation and no compilation.
    ///
    /// ```
    /// use glam::DVec3;
    /// use raypatch::{Camera, Outputs, Region, Request};
    /// # let engine = raypatch::Engine::new(Default::default())?;
    /// let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k4");
    /// let model = engine.load(format!("{golden}/model.safetensors"))?;
    /// let scene = model.encode(&raypatch::SceneData::load(format!("{golden}/scene.safetensors"))?.inputs)?;
    ///
    /// let camera = Camera::msn(DVec3::new(6.0, 4.0, 3.0), 48, 32)?;
    /// let full = scene.render(&camera, &Request::default())?;
    /// let corner = Region { x: 40, y: 0, width: 8, height: 8 };
    /// let part = scene.render(&camera, &Request { region: Some(corner), ..Request::default() })?;
    /// let (full, part) = (full.rgb().unwrap(), part.rgb().unwrap());
    /// assert_eq!((full.width(), full.height(), part.width()), (48, 32, 8));
    /// assert!(full.crop(corner)?.data().iter().zip(part.data()).all(|(a, b)| (a - b).abs() < 1e-6));
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    #[cfg(not(target_family = "wasm"))]
    pub fn render(&self, camera: &Camera, request: &Request) -> Result<Rendered> {
        pollster::block_on(self.render_async(camera, request))
    }

    /// [`render`](Self::render), ready once the GPU is done (the one a browser has).
    pub async fn render_async(&self, camera: &Camera, request: &Request) -> Result<Rendered> {
        self.check_target(camera)?;
        let frame = self.inner.render_async(&self.target_views(camera), *request).await?;
        Ok(Rendered { region: frame.region, outputs: frame.outputs })
    }

    /// Renders several cameras of one image size, one [`Rendered`] per camera, in order: the same pixels as
    /// rendering each alone. They render as many at once (one plan, one submit) as
    /// [`views_per_batch`](Self::views_per_batch) allows, the batches one after another with the GPU kept
    /// busy ([`render_path`](Self::render_path)).
    #[cfg(not(target_family = "wasm"))]
    pub fn render_batch(&self, cameras: &[Camera], request: &Request) -> Result<Vec<Rendered>> {
        let Some(first) = cameras.first() else {
            return Ok(Vec::new());
        };
        let batch = self.views_per_batch(first, request, cameras.len())?;
        self.render_path(cameras, request, batch).collect()
    }

    /// How many cameras like `camera` one render call takes at once, of `count` to render: as many as fit
    /// [`BATCH_BUDGET_BYTES`] of planned GPU memory with no buffer over the adapter's limit, spread evenly over
    /// the calls (so that the last is not much shorter: a path pads it).
    pub fn views_per_batch(&self, camera: &Camera, request: &Request, count: usize) -> Result<usize> {
        self.check_target(camera)?;
        let fit = self.inner.views_within(&self.target_views(camera), *request, BATCH_BUDGET_BYTES)?;
        let calls = count.div_ceil(fit.max(1)).max(1);
        Ok(count.div_ceil(calls).max(1))
    }

    /// The frames of a camera path, rendered as they are taken: `batch` cameras per render call (one plan for
    /// the whole path: a last, shorter batch is filled up with its last camera and the extra frames dropped),
    /// holding no more than two batches of frames. Each batch goes to the GPU before the one before it is read
    /// back, so the GPU renders while the host reads and makes rays. Every camera must have one image size; a
    /// camera that cannot be rendered ends the path with its error after the batches before its own.
    ///
    /// ```
    /// use glam::DVec3;
    /// use raypatch::{Camera, Request};
    /// # let engine = raypatch::Engine::new(Default::default())?;
    /// let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k4");
    /// let model = engine.load(format!("{golden}/model.safetensors"))?;
    /// let scene = model.encode(&raypatch::SceneData::load(format!("{golden}/scene.safetensors"))?.inputs)?;
    /// let cameras: Vec<Camera> = (0..3).map(|i| Camera::msn(DVec3::new(6.0, 4.0 + i as f64, 3.0), 48, 32)).collect::<Result<_, _>>()?;
    /// let frames = scene.render_path(&cameras, &Request::default(), 2).collect::<Result<Vec<_>, _>>()?;
    /// assert_eq!(frames.len(), 3);
    /// assert_eq!(scene.cached_plans(), 1); // one plan of 2 views for both batches
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    #[cfg(not(target_family = "wasm"))]
    pub fn render_path<'s>(&'s self, cameras: &'s [Camera], request: &Request, batch: usize) -> RenderPath<'s> {
        let batch = batch.max(1);
        // The first camera that cannot be rendered: the path stops before its batch.
        let config = &self.inner.model().config;
        let mut failure = None;
        for (i, camera) in cameras.iter().enumerate() {
            let size = |c: &Camera| (c.width(), c.height(), c.pixels_per_ray());
            let checked = self.check_target(camera);
            let checked = checked.and_then(|_| match size(camera) == size(&cameras[0]) {
                true => Ok(()),
                false => Err(Error::Camera(format!(
                    "a batch renders cameras of one size: {}x{} after {}x{}",
                    camera.width(),
                    camera.height(),
                    cameras[0].width(),
                    cameras[0].height()
                ))),
            });
            if let Err(e) = checked {
                failure = Some((i / batch * batch, e));
                break;
            }
        }
        let end = failure.as_ref().map_or(cameras.len(), |(end, _)| *end);
        let failure = failure.map(|(_, e)| e);
        let batches = Batches { cameras, end, batch, kind: config.ray_kind(), next: 0 };
        let renders = self.inner.render_sequence(batches, *request);
        RenderPath { renders, cameras: &cameras[..end], batch, next: 0, ready: Vec::new(), failure }
    }

    /// What rendering `camera` with `request` computes: decoder queries, pixels, dispatches and planned memory
    /// (builds the plan if it does not exist yet).
    pub fn render_stats(&self, camera: &Camera, request: &Request) -> Result<RenderStats> {
        self.check_target(camera)?;
        Ok(self.inner.render_stats(&self.target_views(camera), *request)?)
    }

    /// Renders op by op and returns each op's label and time (for profiling).
    #[cfg(not(target_family = "wasm"))]
    pub fn profile_render(&self, camera: &Camera, request: &Request) -> Result<raypatch_engine::OpTimes> {
        self.check_target(camera)?;
        Ok(self.inner.profile_render(&self.target_views(camera), *request)?)
    }

    /// Checks a target camera against the model's contract: [`Model::check_camera`] and an image size the
    /// patch size allows.
    fn check_target(&self, camera: &Camera) -> Result<()> {
        let config = &self.inner.model().config;
        check_camera(camera, config.ray_kind(), config.position_octaves().1, "target camera")?;
        let sizes = crate::input::PatchSize::of(config);
        crate::input::check_patch_size(sizes, camera.width(), camera.height())
            .map_err(|e| Error::Input(format!("target camera: {e}")))
    }

    /// `camera` as the engine's render target, with rays of the model's kind.
    fn target_views(&self, camera: &Camera) -> raypatch_model::TargetViews {
        camera.target_views_of(self.inner.model().config.ray_kind())
    }

    /// Bytes the encode plan allocated for its intermediates (kept by the model for its next encode of the same
    /// input size; an encode of another size frees them).
    pub fn encode_peak_bytes(&self) -> u64 {
        self.inner.encode_peak_bytes
    }

    /// Bytes the scene keeps on the GPU: the latent and what renders read (for SRT, the decoder's keys and
    /// values).
    pub fn cache_bytes(&self) -> u64 {
        self.inner.latent.bytes() + self.inner.cached.iter().map(|t| t.bytes()).sum::<u64>()
    }

    /// Render plans built so far.
    pub fn cached_plans(&self) -> usize {
        self.inner.cached_render_plans()
    }

    /// The engine-level scene (latent, cached tensors, plan labels), for tools that look inside.
    pub fn engine_scene(&self) -> &EncodedScene<'_> {
        &self.inner
    }
}
