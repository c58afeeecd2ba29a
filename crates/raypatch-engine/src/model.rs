//! The engine's [`Model`]: a family's module tree ([`LightField`]) with its weights on the GPU, loaded once.
//! Encoding a scene with it is the scene core's (`encoded.rs`).
//!
//! Loading starts compiling, on a thread of its own, the pipelines of an encode and a first render at the size
//! the model's config was made for, while the caller goes on (reads its scene, makes its cameras): the first
//! encode then finds them compiled, or waits for the ones still compiling (`gpu/pipelines.rs`).

use std::collections::HashSet;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use raypatch_model::{LoadedModel, ModelConfig};

use crate::device::MatmulKernel;
use crate::error::Result;
use crate::frame::Outputs;
use crate::gpu::Gpu;
use crate::graph::{Graph, HostInput, ImageSize};
use crate::kernels::rays;
use crate::models::{self, LightField};
use crate::nn::ReadLimits;
use crate::plan::{Plan, TensorId};
use crate::render_io::first_render;
use crate::tensor::GpuTensor;
use crate::weights::{GpuWeights, KeptF32, LoadOptions, Precision};

/// A loaded model with its weights on the GPU.
pub struct Model {
    pub(crate) gpu: Arc<Gpu>,
    pub config: ModelConfig,
    pub path: String,
    pub parameter_count: usize,
    pub precision: Precision,
    /// Shared with the load's warm-up thread, which a dropped model leaves to finish on its own.
    pub(crate) family: Arc<dyn LightField>,
    pub(crate) weights: Arc<GpuWeights>,
    /// The plan of the last encode, reused by the next encode of the same input size (`encoded.rs`).
    pub(crate) encode_plan: Mutex<Option<EncodePlan>>,
    /// The load's warm-up while it may still run.
    warm_up: Mutex<Option<JoinHandle<()>>>,
    /// The image sizes (height, width) whose first render's pipelines were compiled, or are compiling: by the
    /// load's warm-up, or beside an encode of input views of that size ([`claim_warm_up`](Self::claim_warm_up)).
    warmed: Mutex<HashSet<(usize, usize)>>,
}

/// The encode plan a [`Model`] keeps for its last input size: an encode of that size again builds nothing.
/// One scene's inputs and outputs at a time: encodes hold the lock until the scene has its own copies.
pub(crate) struct EncodePlan {
    pub size: ImageSize,
    pub plan: Plan,
    pub host_inputs: Vec<(TensorId, HostInput)>,
    pub latent: TensorId,
    pub cached: Vec<TensorId>,
    pub multiply_adds: u64,
}

impl Model {
    pub fn load(gpu: Arc<Gpu>, path: impl AsRef<Path>) -> Result<Model> {
        let loaded = raypatch_model::load_model(path)?;
        Model::from_loaded(gpu, &loaded)
    }

    pub fn from_loaded(gpu: Arc<Gpu>, loaded: &LoadedModel) -> Result<Model> {
        Model::from_loaded_with(gpu, loaded, &LoadOptions::default())
    }

    /// [`from_loaded`](Self::from_loaded) with options (the precision).
    pub fn from_loaded_with(gpu: Arc<Gpu>, loaded: &LoadedModel, options: &LoadOptions) -> Result<Model> {
        let limits =
            ReadLimits { tensor_bytes: gpu.max_buffer_bytes, total_bytes: host_memory_available().unwrap_or(u64::MAX) };
        let (family, weights) = models::build(loaded, limits)?;
        let family: Arc<dyn LightField> = Arc::from(family);
        let weights = Arc::new(weights.upload(&gpu, options)?);
        let nominal = nominal_size(&loaded.config).filter(|&(h, w)| family.check_inputs(h, w).is_ok());
        let warm_up = nominal.and_then(|size| start_warm_up(&gpu, &family, &weights, size));
        let warmed = nominal.filter(|_| warm_up.is_some()).into_iter().collect();
        Ok(Model {
            gpu,
            config: loaded.config.clone(),
            path: loaded.path.clone(),
            parameter_count: loaded.parameter_count(),
            precision: options.precision,
            family,
            weights,
            encode_plan: Mutex::new(None),
            warm_up: Mutex::new(warm_up),
            warmed: Mutex::new(warmed),
        })
    }

    /// Waits for the pipelines the load began compiling in the background (the first encode waits for them
    /// too): for a caller that wants them ready before its first request, or its counters to count only
    /// what follows.
    pub fn finish_warm_up(&self) {
        let warm_up = self.warm_up.lock().expect("warm-up poisoned").take();
        // A pipeline that failed to compile there is compiled again, and its error told, where a plan needs it.
        let _ = warm_up.map(JoinHandle::join);
    }

    /// Whether a first render of input views' size `(height, width)` is still to be warmed up: true once per
    /// size, so that only the first encode of a size records that render.
    pub(crate) fn claim_warm_up(&self, size: (usize, usize)) -> bool {
        self.warmed.lock().expect("warm-up sizes poisoned").insert(size)
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// A plan recording over this model's weights, against the GPU's kernel choice at the model's precision.
    pub(crate) fn graph(&self) -> Graph<'_> {
        graph(&self.gpu, &self.weights)
    }

    /// The outputs this model can render.
    pub fn outputs(&self) -> Outputs {
        self.family.outputs()
    }

    /// Bytes of GPU memory the weights take.
    pub fn weight_bytes(&self) -> u64 {
        self.weights.bytes
    }

    /// The kernel family this model's GEMMs run on: the adapter's, or the tensor kernels (`MatmulKernel::Coop`)
    /// under `Precision::F16Activations` where the device has them (`KernelChoice::at_precision`).
    pub fn kernel_family(&self) -> MatmulKernel {
        self.gpu.kernels.at_precision(self.weights.f16_activations).matmul
    }

    /// How this model computes, for `--timings`, the benchmark's records and logs: its precision and the kernel
    /// family its GEMMs run on, and, where f16-act cannot have the tensor kernels, why.
    pub fn computes_as(&self) -> String {
        let family = self.kernel_family();
        let mut text = format!("precision {}, {} kernels", self.precision.name(), family.name());
        match (self.gpu.kernels.coop, family) {
            (Some(shape), MatmulKernel::Coop) => {
                text += &format!(" (cooperative matrices {0}x{0}x{0}, {1}-lane subgroups)", shape.tile, shape.lanes)
            }
            _ if self.precision == Precision::F16Activations => {
                let why = self.gpu.without_coop.as_deref().unwrap_or("the kernel family was forced");
                text += &format!(": no tensor kernels on this device ({why}), so f16-act runs on these")
            }
            _ => {}
        }
        text
    }

    /// Linear layers whose weights stay f32 under an f16 precision (a weight beyond f16's range).
    pub fn weights_kept_f32(&self) -> &[KeptF32] {
        &self.weights.kept_f32
    }
}

/// A plan recording over `weights`, against the GPU's kernel choice at the weights' precision.
fn graph<'a>(gpu: &'a Gpu, weights: &'a GpuWeights) -> Graph<'a> {
    let mut g = Graph::new(gpu, &weights.tensors);
    g.b.kernels = g.b.kernels.at_precision(weights.f16_activations);
    g
}

/// The image size `(height, width)` a model's config was made for, where it says: a Ray-Patch decoder's output
/// size (`h_out`×`w_out`, which the official runs set to their image size), else its patch grid (`h_in`×`w_in`)
/// of k×k patches. The other decoders' configs name no size.
fn nominal_size(config: &ModelConfig) -> Option<(usize, usize)> {
    let rp = config.ray_patch()?;
    let k = rp.patch_size();
    Some(rp.resize_out.unwrap_or((rp.grid_in.0 * k, rp.grid_in.1 * k)))
}

/// Starts compiling, on a thread of its own, the pipelines of encoding one input view of `(height, width)`
/// and of a first render of that size (the encoder's first: the first encode asks for them first), then
/// probes whether the GPU makes pinhole rays (`kernels::rays::exact_on`). `None`
/// where no thread could be started: the plans then compile them when built.
fn start_warm_up(
    gpu: &Arc<Gpu>,
    family: &Arc<dyn LightField>,
    weights: &Arc<GpuWeights>,
    (height, width): (usize, usize),
) -> Option<JoinHandle<()>> {
    let (gpu, family, weights) = (gpu.clone(), family.clone(), weights.clone());
    let warm = move || {
        let Some(any) = weights.tensors.first() else { return };
        let mut g = graph(&gpu, &weights);
        let encoded = family.encode(&mut g, ImageSize { n: 1, h: height, w: width });
        let encoder = g.b;
        // The scene's tensors as the encode would make them: their shapes pick the render's kernels, and the
        // recording binds no buffer, so any buffer stands in.
        let cached: Vec<GpuTensor> = (encoded.cached.iter().map(|t| t.id()))
            .map(|id| GpuTensor {
                buffer: any.buffer.clone(),
                rows: encoder.rows(id),
                cols: encoder.cols(id),
                dtype: encoder.dtype(id),
            })
            .collect();
        let render = first_render(graph(&gpu, &weights), &*family, &cached, (height, width));
        gpu.compile_pipelines(encoder.pipelines().chain(render.iter().flat_map(|r| r.pipelines())));
        // Whether this GPU makes pinhole rays (a probe run once per GPU): found here, not in the first render.
        pollster::block_on(rays::exact_on(&gpu));
    };
    // A browser has no threads (its plans compile their pipelines when built).
    if cfg!(target_family = "wasm") {
        return None;
    }
    std::thread::Builder::new().name("raypatch-warm-up".into()).spawn(warm).ok()
}

/// The host memory available to this process now, where the system says: Linux's `MemAvailable`, less where
/// the process's cgroup (v2) allows less.
fn host_memory_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let system = line.split_whitespace().nth(1)?.parse::<u64>().ok()?.checked_mul(1024)?;
    let cgroup = || -> Option<u64> {
        let read = |name: &str| std::fs::read_to_string(format!("/sys/fs/cgroup/{name}")).ok();
        let max: u64 = read("memory.max")?.trim().parse().ok()?; // "max" (no limit) does not parse
        let current: u64 = read("memory.current")?.trim().parse().ok()?;
        Some(max.saturating_sub(current))
    };
    Some(cgroup().map_or(system, |c| c.min(system)))
}
