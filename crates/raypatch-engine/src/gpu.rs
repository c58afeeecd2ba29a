//! The GPU context: adapter choice, device, pipeline cache, uploads (readbacks: `readback.rs`).

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};

use crate::device::{CoopShape, KernelChoice, MatmulKernel, COOP_TUNING_FILE};

mod mapping;
mod pipelines;
mod readback;
mod staging;
mod timestamps;

use crate::error::{EngineError, Result};
use crate::pipeline_cache::{self, DiskCache, PipelineCacheDir, PipelineCacheStatus};
use crate::tensor::{padded_cols, Dtype, GpuTensor};
use pipelines::Pipelines;
pub(crate) use readback::ReadPart;
pub(crate) use staging::Staging;
pub(crate) use timestamps::Timestamps;
pub use timestamps::{GpuTimes, OpTime, TimestampMode};

/// One WGSL file: a kernel family. Its entry points are the kernels.
#[derive(Debug)]
pub struct Shader {
    pub name: &'static str,
    pub source: &'static str,
    /// A variant of the same source (e.g. f16 weights): a prefix (WGSL `enable` directives) and text
    /// replacements applied when compiling, each of which must occur in `source` exactly once.
    pub prefix: &'static str,
    pub replace: &'static [(&'static str, &'static str)],
    /// Features the variant needs.
    pub features: wgpu::Features,
}

impl Shader {
    /// The WGSL this shader compiles: `source` with the variant's prefix and replacements.
    pub fn wgsl(&self) -> std::borrow::Cow<'static, str> {
        if self.prefix.is_empty() && self.replace.is_empty() {
            return self.source.into();
        }
        let mut text = format!("{}{}", self.prefix, self.source);
        for (from, to) in self.replace {
            assert_eq!(text.matches(from).count(), 1, "shader {}: `{from}` must occur exactly once", self.name);
            text = text.replace(from, to);
        }
        text.into()
    }
}

/// Which adapter to run on.
#[derive(Clone, Debug, Default)]
pub enum AdapterChoice {
    /// A real GPU when there is one, a software (CPU) adapter such as lavapipe otherwise.
    #[default]
    Auto,
    /// The first adapter whose name contains this text (case-insensitive).
    NameContains(String),
}

#[derive(Clone, Debug, Default)]
pub struct GpuOptions {
    pub adapter: AdapterChoice,
    /// The largest buffer the engine may bind, in bytes, when below the adapter's own limit (to bound memory;
    /// `None`: the adapter's limit). Renders whose buffers would be larger run in row bands.
    pub max_buffer_bytes: Option<u64>,
    /// The matmul kernel of linear layers; `None`: the adapter's best ([`MatmulKernel::best_for`]).
    pub matmul: Option<MatmulKernel>,
    /// Leave the adapter's subgroup operations unused: the kernels run their variants without them (flash
    /// attention a query row per invocation; no `matmul_lanes`), to compare the two on one adapter.
    pub without_subgroups: bool,
    /// Make pinhole cameras' rays on the host and upload them, as on a GPU whose rays are not bit-equal to the
    /// host's (`kernels::rays::exact_on`), to compare the two on one adapter.
    pub rays_on_host: bool,
    /// Where compiled pipelines are kept between runs, on backends with a pipeline cache (Vulkan); see
    /// [`pipeline_cache`].
    pub pipeline_cache: PipelineCacheDir,
}

/// Counters that let tests and the benchmark see what the engine did.
#[derive(Debug, Default)]
pub struct GpuCounters {
    pub pipelines_compiled: AtomicU64,
    /// Nanoseconds spent compiling them (shader modules and compute pipelines).
    pub pipeline_compile_nanos: AtomicU64,
    /// Buffers of every kind: plans' tensors, weights, scenes' tensors, and the staging buffers uploads and
    /// readbacks go through.
    pub buffers_created: AtomicU64,
    /// Textures: plans' scratch textures and packed weights (`matmul_lanes`).
    pub textures_created: AtomicU64,
    /// Bytes of buffers and textures.
    pub bytes_allocated: AtomicU64,
    pub submits: AtomicU64,
    pub dispatches: AtomicU64,
}

#[derive(Clone, Debug, Copy, Default)]
pub struct CounterSnapshot {
    pub pipelines_compiled: u64,
    pub pipeline_compile_nanos: u64,
    pub buffers_created: u64,
    pub textures_created: u64,
    pub bytes_allocated: u64,
    pub submits: u64,
    pub dispatches: u64,
}

pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// The optional features the device was created with (those of [`OPTIONAL_FEATURES`] it has, and cooperative
    /// matrices where `Coop` can use them: [`KernelChoice::coop`]).
    pub features: wgpu::Features,
    /// The largest buffer the engine binds: the adapter's limit, or the smaller one asked for.
    pub max_buffer_bytes: u64,
    /// Kernel variants plans record on this adapter.
    pub kernels: KernelChoice,
    /// Why the tensor kernels (`MatmulKernel::Coop`) cannot run here, where they cannot: the f16-act precision
    /// then runs on the adapter's other kernels (`--timings` says so).
    pub without_coop: Option<String>,
    pipelines: Mutex<Pipelines>,
    /// Each shader's module, parsed and validated once for all its entry points and constants.
    modules: Mutex<HashMap<&'static str, Arc<wgpu::ShaderModule>>>,
    /// The driver's cache of compiled pipelines, kept on disk between runs (written when dropped).
    pub(crate) pipeline_cache: DiskCache,
    /// Constant tensors (weights, scenes' keys and values) packed into textures for `matmul_lanes`, per
    /// tensor buffer (dropped after it).
    kept_textures: Mutex<Vec<KeptEntry>>,
    /// The readback buffer of [`read`](Self::read) and encodes (renders keep their own with their plans).
    readback: Mutex<Option<wgpu::Buffer>>,
    pub counters: GpuCounters,
    pub(crate) timestamps: Mutex<Timestamps>,
    /// Whether this GPU makes a pinhole camera's rays bit-equal to the host's: probed on first use
    /// (`kernels::rays::exact_on`).
    pub(crate) exact_pinhole_rays: std::sync::OnceLock<bool>,
}

/// Features the engine uses when the adapter has them: GPU timestamps around plans and between their ops,
/// f16 in shaders (weights stored as f16), and subgroup operations (`matmul_lanes`, flash attention's subgroup
/// variant).
pub const OPTIONAL_FEATURES: wgpu::Features = wgpu::Features::TIMESTAMP_QUERY
    .union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES)
    .union(wgpu::Features::SHADER_F16)
    .union(wgpu::Features::SUBGROUP);

/// A constant tensor's packed texture, kept while the tensor's buffer lives.
struct KeptEntry {
    buffer: Weak<wgpu::Buffer>,
    /// Which packing of the tensor (the kernel's key for it).
    key: u64,
    texture: Arc<wgpu::Texture>,
}

/// Adapters in the order Auto tries them: discrete and integrated GPUs before virtual and CPU ones, and
/// among equals the native APIs (Vulkan, Metal, DX12) before OpenGL.
fn adapter_rank(info: &wgpu::AdapterInfo) -> (u32, bool) {
    let kind = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    (kind, info.backend == wgpu::Backend::Gl)
}

/// Every adapter wgpu can see, best first.
#[cfg(not(target_family = "wasm"))]
pub fn list_adapters() -> Vec<wgpu::AdapterInfo> {
    pollster::block_on(list_adapters_async())
}

/// Every adapter wgpu can see, best first (in a browser: its one adapter).
pub async fn list_adapters_async() -> Vec<wgpu::AdapterInfo> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let mut infos: Vec<_> = (instance.enumerate_adapters(wgpu::Backends::all()).await)
        .into_iter()
        .filter(|a| a.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS))
        .map(|a| a.get_info())
        .collect();
    infos.sort_by_key(adapter_rank);
    infos
}

impl Gpu {
    /// The device on the adapter `options` choose (in a browser, its WebGPU adapter), with the kernels that fit
    /// its features and limits.
    pub async fn new_async(options: &GpuOptions) -> Result<Gpu> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        let mut adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
        adapters.retain(|a| a.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS));
        adapters.sort_by_key(|a| adapter_rank(&a.get_info()));
        let adapter = match &options.adapter {
            AdapterChoice::Auto => adapters.into_iter().next(),
            AdapterChoice::NameContains(text) => {
                let text = text.to_lowercase();
                adapters.into_iter().find(|a| a.get_info().name.to_lowercase().contains(&text))
            }
        }
        .ok_or_else(|| match &options.adapter {
            AdapterChoice::Auto => EngineError::NoAdapter(
                "no adapter with compute shaders found (install a Vulkan driver, e.g. Mesa lavapipe)".into(),
            ),
            AdapterChoice::NameContains(t) => {
                EngineError::AdapterNotFound(format!("no adapter whose name contains {t:?} (see --list-adapters)"))
            }
        })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        crate::device::check_limits(&limits).map_err(|why| EngineError::Device(format!("{}: {why}", info.name)))?;
        let mut features = adapter.features() & OPTIONAL_FEATURES;
        if options.without_subgroups {
            features.remove(wgpu::Features::SUBGROUP);
        }
        // Cooperative matrices (MatmulKernel::Coop) only where the tensor kernels have a shape for the adapter: an
        // experimental feature, asked for nowhere else (wgpu lists it on an llvmpipe too narrow for it, where
        // making the device would panic; CoopShape::of_adapter rules that out).
        let coop_shape = CoopShape::of_adapter(
            &info,
            adapter.features() & (features | wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX),
            &adapter.cooperative_matrix_properties(),
            &limits,
        );
        // The GPU kit's tuned tilings for this adapter, where its tuner wrote them (read only where the tensor
        // kernels can run).
        let coop_shape = coop_shape.map(|shape| {
            let dir = options.pipeline_cache.resolve().ok();
            match dir.and_then(|dir| std::fs::read_to_string(dir.join(COOP_TUNING_FILE)).ok()) {
                Some(tuning) => shape.tuned(&tuning, &info.name, &limits),
                None => shape,
            }
        });
        let cache_file = pipeline_cache::cache_file(&options.pipeline_cache, &adapter);
        let request = |features: wgpu::Features, experimental_features| {
            adapter.request_device(&wgpu::DeviceDescriptor {
                label: Some("raypatch"),
                required_features: features | pipeline_cache::features(&cache_file),
                required_limits: limits.clone(),
                experimental_features,
                ..Default::default()
            })
        };
        let with_coop = match coop_shape {
            Ok(shape) => {
                // SAFETY: wgpu marks its experimental features unsafe for possible bugs in their implementation;
                // only the tensor kernels use this one, and their tests check their results on every adapter that
                // has it (.ci/coop.sh: Mesa's lavapipe with Khronos' validation layer).
                let experimental = unsafe { wgpu::ExperimentalFeatures::enabled() };
                let device = request(features | wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX, experimental).await;
                device
                    .map(|(device, queue)| (device, queue, shape))
                    .map_err(|e| format!("the device could not be made with cooperative matrices: {e}"))
            }
            Err(why) => Err(why),
        };
        // Where the experimental feature cannot be had, the device is made without it (no `Coop`), and why is kept.
        let (device, queue, coop) = match with_coop {
            Ok((device, queue, shape)) => {
                features |= wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX;
                (device, queue, Ok(shape))
            }
            Err(why) => {
                let (device, queue) = request(features, wgpu::ExperimentalFeatures::disabled())
                    .await
                    .map_err(|e| EngineError::Device(e.to_string()))?;
                (device, queue, Err(why))
            }
        };
        let adapter_max = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let max_buffer_bytes = options.max_buffer_bytes.map_or(adapter_max, |m| m.min(adapter_max));
        let matmul = match options.matmul {
            None => MatmulKernel::best_for(&info, features, &limits),
            Some(kernel) => {
                if let Err(why) = kernel.supported(&info, features).and_then(|()| kernel.fits(&limits)) {
                    return Err(EngineError::Request(format!("matmul kernel {kernel:?} on {}: {why}", info.name)));
                }
                kernel
            }
        };
        let max_texels = TEXTURE_WIDTH * limits.max_texture_dimension_2d as usize;
        let pipeline_cache = DiskCache::open(&device, cache_file);
        let subgroups = KernelChoice::subgroups_suit(&info, features);
        let shaped = info.device_type != wgpu::DeviceType::Cpu;
        Ok(Gpu {
            device,
            queue,
            info,
            limits,
            features,
            max_buffer_bytes,
            kernels: KernelChoice {
                matmul,
                max_texels,
                f16_activations: false,
                pinned: false,
                subgroups,
                shaped,
                coop: coop.as_ref().ok().copied(),
            },
            without_coop: coop.err(),
            pipelines: Mutex::new(HashMap::new()),
            modules: Mutex::new(HashMap::new()),
            pipeline_cache,
            kept_textures: Mutex::new(Vec::new()),
            readback: Mutex::new(None),
            exact_pinhole_rays: if options.rays_on_host { false.into() } else { std::sync::OnceLock::new() },
            counters: GpuCounters::default(),
            timestamps: Mutex::new(Timestamps::default()),
        })
    }

    /// "name (backend, driver)" for logs and benchmark records.
    pub fn describe(&self) -> String {
        format!("{} ({:?}, {} {})", self.info.name, self.info.backend, self.info.driver, self.info.driver_info)
    }

    /// A buffer, counted in [`counters`](Self::counters) (staging buffers included).
    pub(crate) fn create_buffer(&self, label: &str, bytes: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.new_buffer(label, bytes, usage, false)
    }

    /// A buffer mapped for writing from the start.
    pub(crate) fn create_buffer_mapped(&self, label: &str, bytes: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.new_buffer(label, bytes, usage, true)
    }

    fn new_buffer(&self, label: &str, bytes: u64, usage: wgpu::BufferUsages, mapped: bool) -> wgpu::Buffer {
        // wgpu rejects empty bindings; a 16-byte floor keeps zero-row tensors legal.
        let size = bytes.max(16);
        self.counters.buffers_created.fetch_add(1, Ordering::Relaxed);
        self.counters.bytes_allocated.fetch_add(size, Ordering::Relaxed);
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: mapped,
        })
    }

    /// An rgba32float storage texture of at least `texels` texels, [`TEXTURE_WIDTH`] wide.
    pub(crate) fn create_texture(&self, label: &str, texels: usize) -> Result<wgpu::Texture> {
        let (width, height) = texture_size(texels);
        if height > self.limits.max_texture_dimension_2d {
            return Err(EngineError::Request(format!(
                "{label}: a texture of {texels} texels needs {height} rows, more than the adapter's {}",
                self.limits.max_texture_dimension_2d
            )));
        }
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::STORAGE_BINDING,
            view_formats: &[],
        });
        self.counters.textures_created.fetch_add(1, Ordering::Relaxed);
        self.counters.bytes_allocated.fetch_add(texture_bytes(&texture), Ordering::Relaxed);
        Ok(texture)
    }

    /// The texture kept with a constant tensor (a weight, a scene's keys or values) under `key` (a packing of
    /// it that `matmul_lanes` reads): `make` makes it the first time, and it is kept while the tensor's buffer
    /// lives (a texture outliving its buffer is dropped at the next call).
    pub(crate) fn kept_texture(
        &self,
        tensor: &GpuTensor,
        key: u64,
        make: impl FnOnce() -> Result<Arc<wgpu::Texture>>,
    ) -> Result<Arc<wgpu::Texture>> {
        let mut kept = self.kept_textures.lock().expect("kept textures poisoned");
        kept.retain(|k| k.buffer.strong_count() > 0);
        let buffer = Arc::downgrade(&tensor.buffer);
        if let Some(k) = kept.iter().find(|k| k.buffer.ptr_eq(&buffer) && k.key == key) {
            return Ok(k.texture.clone());
        }
        let texture = make()?;
        kept.push(KeptEntry { buffer, key, texture: texture.clone() });
        Ok(texture)
    }

    /// Where compiled pipelines are kept between runs, or why they are not.
    pub fn pipeline_cache_status(&self) -> PipelineCacheStatus {
        self.pipeline_cache.status()
    }

    /// Writes the pipeline cache to its file now if pipelines were compiled since it was last written (the
    /// Gpu also does when dropped). Whether it wrote; `Ok(false)` without a cache.
    pub fn save_pipeline_cache(&self) -> std::io::Result<bool> {
        self.pipeline_cache.save()
    }

    /// Checks that a buffer of `bytes` can be bound as one storage buffer (see [`Gpu::max_buffer_bytes`]).
    pub fn check_binding_size(&self, what: &str, bytes: u64) -> Result<()> {
        let max = self.max_buffer_bytes;
        if bytes > max {
            return Err(EngineError::TooLarge { what: what.to_string(), bytes, max });
        }
        Ok(())
    }

    /// Uploads a row-major `[rows, cols]` f32 matrix, padding each row to the engine's row stride.
    pub fn upload(&self, label: &str, rows: usize, cols: usize, data: &[f32]) -> Result<GpuTensor> {
        assert_eq!(data.len(), rows * cols, "upload of {label}: data length does not match {rows}x{cols}");
        let ld = padded_cols(cols);
        let bytes = (rows * ld * 4) as u64;
        self.check_binding_size(label, bytes)?;
        let buffer = self.create_buffer(label, bytes, storage_usage());
        if rows > 0 {
            let padded = pad_rows(data, rows, cols);
            self.queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&padded));
        }
        Ok(GpuTensor { buffer: Arc::new(buffer), rows, cols, dtype: Dtype::F32 })
    }

    /// Uploads a row-major `[rows, cols]` matrix as f16 (round to nearest even), rows padded to a multiple
    /// of 8 halves. The caller checks that every value is within f16 range (|x| ≤ 65504): out-of-range
    /// values are an error here, never silently infinity.
    pub fn upload_f16(&self, label: &str, rows: usize, cols: usize, data: &[f32]) -> Result<GpuTensor> {
        assert_eq!(data.len(), rows * cols, "upload of {label}: data length does not match {rows}x{cols}");
        let ld = Dtype::F16.ld(cols);
        let mut halves = vec![half::f16::ZERO; rows * ld];
        for (r, row) in data.chunks_exact(cols.max(1)).enumerate() {
            for (c, &v) in row.iter().enumerate() {
                let h = half::f16::from_f32(v);
                if !h.is_finite() {
                    return Err(EngineError::Request(format!(
                        "{label}: element [{r}, {c}] = {v} is outside the f16 range (|x| <= 65504)"
                    )));
                }
                halves[r * ld + c] = h;
            }
        }
        let bytes = (rows * ld * 2) as u64;
        self.check_binding_size(label, bytes)?;
        let buffer = self.create_buffer(label, bytes, storage_usage());
        if rows > 0 {
            let words: Vec<u16> = halves.iter().map(|h| h.to_bits()).collect();
            self.queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&words));
        }
        Ok(GpuTensor { buffer: Arc::new(buffer), rows, cols, dtype: Dtype::F16 })
    }

    /// Writes a row-major `[rows, cols]` matrix into an existing tensor of that shape.
    pub fn write(&self, tensor: &GpuTensor, data: &[f32]) {
        assert_eq!(data.len(), tensor.rows * tensor.cols, "write: data length does not match the tensor");
        if tensor.rows > 0 {
            let padded = pad_rows(data, tensor.rows, tensor.cols);
            self.queue.write_buffer(&tensor.buffer, 0, bytemuck::cast_slice(&padded));
        }
    }

    /// Submits `encoder`'s work (counted in [`counters`](Self::counters)).
    pub(crate) fn submit(&self, encoder: wgpu::CommandEncoder) -> wgpu::SubmissionIndex {
        self.counters.submits.fetch_add(1, Ordering::Relaxed);
        self.queue.submit([encoder.finish()])
    }

    pub fn counters(&self) -> CounterSnapshot {
        let c = &self.counters;
        CounterSnapshot {
            pipelines_compiled: c.pipelines_compiled.load(Ordering::Relaxed),
            pipeline_compile_nanos: c.pipeline_compile_nanos.load(Ordering::Relaxed),
            buffers_created: c.buffers_created.load(Ordering::Relaxed),
            textures_created: c.textures_created.load(Ordering::Relaxed),
            bytes_allocated: c.bytes_allocated.load(Ordering::Relaxed),
            submits: c.submits.load(Ordering::Relaxed),
            dispatches: c.dispatches.load(Ordering::Relaxed),
        }
    }
}

pub(crate) fn storage_usage() -> wgpu::BufferUsages {
    wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC
}

fn pad_rows(data: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let ld = padded_cols(cols);
    if ld == cols {
        return data.to_vec();
    }
    let mut padded = vec![0.0f32; rows * ld];
    for r in 0..rows {
        padded[r * ld..r * ld + cols].copy_from_slice(&data[r * cols..(r + 1) * cols]);
    }
    padded
}

/// Bytes of an rgba32float texture.
pub(crate) fn texture_bytes(texture: &wgpu::Texture) -> u64 {
    texture.width() as u64 * texture.height() as u64 * 16
}

/// Texels per row of the engine's textures (`TEXTURE_WIDTH` in `shaders/texels.wgsl`).
pub const TEXTURE_WIDTH: usize = 4096;

/// Width and height of a texture holding `texels` texels.
pub fn texture_size(texels: usize) -> (u32, u32) {
    (TEXTURE_WIDTH as u32, texels.div_ceil(TEXTURE_WIDTH).max(1) as u32)
}
