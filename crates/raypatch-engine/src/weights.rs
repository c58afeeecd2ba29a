//! A model's weights on the GPU: how each prepared weight of a [`WeightSet`] is stored there (f32, or f16 for
//! linear layers where asked and in range; conv weights packed for their kernel), uploaded once per model.

use crate::error::{EngineError, Result};
use crate::gpu::Gpu;
use crate::kernels::conv::pack_conv;
use crate::nn::{Layout, WeightSet};
use crate::tensor::GpuTensor;

/// How the linear layers' weights are stored on the GPU (they are most of the bytes and of the time).
/// Everything else (convolutions, biases, norms, activations) stays f32, and all arithmetic is f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum WeightStorage {
    #[default]
    F32,
    /// f16 (needs the adapter's `SHADER_F16`). A layer with a weight beyond f16's range (|w| > 65504,
    /// which f16 would turn into infinity) stays f32 and is listed in [`GpuWeights::kept_f32`].
    F16,
}

/// Options for putting a model on the GPU.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    pub weight_storage: WeightStorage,
}

/// A linear layer that stays f32 under [`WeightStorage::F16`], and why.
#[derive(Clone, Debug, PartialEq)]
pub struct KeptF32 {
    pub tensor: String,
    /// The largest |weight|, beyond f16's range.
    pub max_abs: f32,
}

/// A model's weights on the GPU, indexed by [`Param`](crate::graph::Param).
pub struct GpuWeights {
    pub tensors: Vec<GpuTensor>,
    /// Bytes of GPU memory the weights take.
    pub bytes: u64,
    /// Linear layers kept in f32 under [`WeightStorage::F16`] because a weight is beyond f16's range.
    pub kept_f32: Vec<KeptF32>,
}

impl WeightSet {
    /// Puts every prepared weight on the GPU in the layout its kernel reads.
    pub fn upload(&self, gpu: &Gpu, options: &LoadOptions) -> Result<GpuWeights> {
        if options.weight_storage == WeightStorage::F16 && !gpu.features.contains(wgpu::Features::SHADER_F16) {
            return Err(EngineError::Request(format!(
                "f16 weights need shader-f16, which {} does not have",
                gpu.info.name
            )));
        }
        let mut weights =
            GpuWeights { tensors: Vec::with_capacity(self.prepared.len()), bytes: 0, kept_f32: Vec::new() };
        for p in &self.prepared {
            let data = p.data.to_f32();
            let tensor = match p.layout {
                Layout::Row => gpu.upload(&p.name, 1, data.len(), &data)?,
                Layout::Dense { rows, cols } => gpu.upload(&p.name, rows, cols, &data)?,
                Layout::Conv { cout, cin, kernel } => {
                    let packed = pack_conv(&data, cout, cin, kernel);
                    gpu.upload(&p.name, cout, packed.len() / cout, &packed)?
                }
                Layout::Matrix { rows, cols } => {
                    let max_abs = data.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                    match options.weight_storage {
                        WeightStorage::F16 if half::f16::from_f32(max_abs).is_finite() => {
                            gpu.upload_f16(&p.name, rows, cols, &data)?
                        }
                        WeightStorage::F16 => {
                            weights.kept_f32.push(KeptF32 { tensor: p.name.clone(), max_abs });
                            gpu.upload(&p.name, rows, cols, &data)?
                        }
                        WeightStorage::F32 => gpu.upload(&p.name, rows, cols, &data)?,
                    }
                }
            };
            weights.bytes += tensor.bytes();
            weights.tensors.push(tensor);
        }
        Ok(weights)
    }
}
