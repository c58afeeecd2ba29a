//! The engine's [`Model`]: a family's module tree ([`LightField`]) with its weights on the GPU, loaded once.
//! Encoding a scene with it is the scene core's (`encoded.rs`).

use std::path::Path;
use std::sync::{Arc, Mutex};

use raypatch_model::{LoadedModel, ModelConfig};

use crate::error::Result;
use crate::frame::Outputs;
use crate::gpu::Gpu;
use crate::graph::{Graph, HostInput, ImageSize};
use crate::models::{self, LightField};
use crate::nn::ReadLimits;
use crate::plan::{Plan, TensorId};
use crate::weights::{GpuWeights, KeptF32, LoadOptions};

/// A loaded model with its weights on the GPU.
pub struct Model {
    pub(crate) gpu: Arc<Gpu>,
    pub config: ModelConfig,
    pub path: String,
    pub parameter_count: usize,
    pub(crate) family: Box<dyn LightField>,
    pub(crate) weights: GpuWeights,
    /// The plan of the last encode, reused by the next encode of the same input size (`encoded.rs`).
    pub(crate) encode_plan: Mutex<Option<EncodePlan>>,
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
        let weights = weights.upload(&gpu, options)?;
        Ok(Model {
            gpu,
            config: loaded.config.clone(),
            path: loaded.path.clone(),
            parameter_count: loaded.parameter_count(),
            family,
            weights,
            encode_plan: Mutex::new(None),
        })
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// A plan recording over this model's weights, against the GPU's kernel choice at the model's precision.
    pub(crate) fn graph(&self) -> Graph<'_> {
        let mut g = Graph::new(&self.gpu, &self.weights.tensors);
        g.b.kernels.f16_activations = self.weights.f16_activations;
        g
    }

    /// The outputs this model can render.
    pub fn outputs(&self) -> Outputs {
        self.family.outputs()
    }

    /// Bytes of GPU memory the weights take.
    pub fn weight_bytes(&self) -> u64 {
        self.weights.bytes
    }

    /// Linear layers whose weights stay f32 under an f16 precision (a weight beyond f16's range).
    pub fn weights_kept_f32(&self) -> &[KeptF32] {
        &self.weights.kept_f32
    }
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
