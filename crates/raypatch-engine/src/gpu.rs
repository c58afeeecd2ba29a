//! The GPU context: adapter choice, device, pipeline cache, uploads and readbacks.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use crate::error::{EngineError, Result};
use crate::tensor::{padded_cols, GpuTensor};

/// One WGSL file: a kernel family. Its entry points are the kernels.
#[derive(Debug)]
pub struct Shader {
    pub name: &'static str,
    pub source: &'static str,
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
}

/// Counters that let tests and the benchmark see what the engine did.
#[derive(Debug, Default)]
pub struct GpuCounters {
    pub pipelines_compiled: AtomicU64,
    pub buffers_created: AtomicU64,
    pub bytes_allocated: AtomicU64,
    pub submits: AtomicU64,
    pub dispatches: AtomicU64,
}

#[derive(Clone, Debug, Copy, Default)]
pub struct CounterSnapshot {
    pub pipelines_compiled: u64,
    pub buffers_created: u64,
    pub bytes_allocated: u64,
    pub submits: u64,
    pub dispatches: u64,
}

pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    pipelines: Mutex<HashMap<(&'static str, &'static str), Arc<wgpu::ComputePipeline>>>,
    pub counters: GpuCounters,
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
pub fn list_adapters() -> Vec<wgpu::AdapterInfo> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let mut infos: Vec<_> = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
        .into_iter()
        .map(|a| a.get_info())
        .collect();
    infos.sort_by_key(adapter_rank);
    infos
}

impl Gpu {
    pub fn new(options: &GpuOptions) -> Result<Gpu> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        adapters.retain(|a| a.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS));
        adapters.sort_by_key(|a| adapter_rank(&a.get_info()));
        let adapter = match &options.adapter {
            AdapterChoice::Auto => adapters.into_iter().next(),
            AdapterChoice::NameContains(text) => {
                let text = text.to_lowercase();
                adapters.into_iter().find(|a| a.get_info().name.to_lowercase().contains(&text))
            }
        }
        .ok_or_else(|| EngineError::NoAdapter(match &options.adapter {
            AdapterChoice::Auto => "no adapter with compute shaders found (install a Vulkan driver, e.g. Mesa lavapipe)".into(),
            AdapterChoice::NameContains(t) => format!("no adapter whose name contains {t:?} (see --list-adapters)"),
        }))?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("raypatch"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| EngineError::Device(e.to_string()))?;
        Ok(Gpu { device, queue, info, limits, pipelines: Mutex::new(HashMap::new()), counters: GpuCounters::default() })
    }

    /// "name (backend, driver)" for logs and benchmark records.
    pub fn describe(&self) -> String {
        format!("{} ({:?}, {} {})", self.info.name, self.info.backend, self.info.driver, self.info.driver_info)
    }

    /// The compute pipeline of `shader`'s `entry`, compiled on first use and cached for the life of the Gpu.
    pub fn pipeline(&self, shader: &'static Shader, entry: &'static str) -> Arc<wgpu::ComputePipeline> {
        let mut cache = self.pipelines.lock().expect("pipeline cache poisoned");
        cache
            .entry((shader.name, entry))
            .or_insert_with(|| {
                self.counters.pipelines_compiled.fetch_add(1, Ordering::Relaxed);
                let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(shader.name),
                    source: wgpu::ShaderSource::Wgsl(shader.source.into()),
                });
                Arc::new(self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                }))
            })
            .clone()
    }

    pub(crate) fn create_buffer(&self, label: &str, bytes: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.counters.buffers_created.fetch_add(1, Ordering::Relaxed);
        self.counters.bytes_allocated.fetch_add(bytes, Ordering::Relaxed);
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            // wgpu rejects empty bindings; a 16-byte floor keeps zero-row tensors legal.
            size: bytes.max(16),
            usage,
            mapped_at_creation: false,
        })
    }

    /// Checks that a buffer of `bytes` can be bound as one storage buffer on this adapter.
    pub fn check_binding_size(&self, what: &str, bytes: u64) -> Result<()> {
        let max = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
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
        Ok(GpuTensor { buffer: Arc::new(buffer), rows, cols })
    }

    /// Writes a row-major `[rows, cols]` matrix into an existing tensor of that shape.
    pub fn write(&self, tensor: &GpuTensor, data: &[f32]) {
        assert_eq!(data.len(), tensor.rows * tensor.cols, "write: data length does not match the tensor");
        if tensor.rows > 0 {
            let padded = pad_rows(data, tensor.rows, tensor.cols);
            self.queue.write_buffer(&tensor.buffer, 0, bytemuck::cast_slice(&padded));
        }
    }

    /// Reads a tensor back as a row-major `[rows, cols]` matrix (row padding removed). Waits for the GPU.
    pub fn read(&self, tensor: &GpuTensor) -> Result<Vec<f32>> {
        self.read_rows(&tensor.buffer, 0, tensor.rows, tensor.cols)
    }

    /// Reads rows `[row_start, row_start + rows)` of a `cols`-wide tensor stored in `buffer`.
    pub fn read_rows(&self, buffer: &wgpu::Buffer, row_start: usize, rows: usize, cols: usize) -> Result<Vec<f32>> {
        let ld = padded_cols(cols);
        let bytes = (rows * ld * 4) as u64;
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, (row_start * ld * 4) as u64, &staging, 0, bytes);
        self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| EngineError::Device("readback callback dropped".into()))?
            .map_err(|e| EngineError::Device(format!("mapping a readback buffer: {e}")))?;
        let mapped = slice.get_mapped_range().map_err(|e| EngineError::Device(format!("reading back: {e}")))?;
        let words: &[f32] = bytemuck::cast_slice(&mapped);
        let mut out = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            out.extend_from_slice(&words[r * ld..r * ld + cols]);
        }
        drop(mapped);
        staging.unmap();
        Ok(out)
    }

    /// Blocks until the GPU has finished all submitted work.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| EngineError::Device(format!("waiting for the GPU: {e}")))
    }

    pub fn counters(&self) -> CounterSnapshot {
        let c = &self.counters;
        CounterSnapshot {
            pipelines_compiled: c.pipelines_compiled.load(Ordering::Relaxed),
            buffers_created: c.buffers_created.load(Ordering::Relaxed),
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
