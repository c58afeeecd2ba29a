//! A model's weights on the GPU: how each prepared weight of a [`WeightSet`] is stored there (f32, or f16 for
//! linear layers where asked and in range; conv weights packed for their kernel), uploaded once per model.

use crate::error::{EngineError, Result};
use crate::gpu::Gpu;
use crate::kernels::conv::pack_conv;
use crate::nn::{Layout, WeightSet};
use crate::tensor::GpuTensor;

/// The precision a model runs at. Its linear layers' weights are most of the bytes and of the time; everything
/// else (convolutions, biases, norms, attention, what layers hand each other) stays f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// f32 storage and arithmetic.
    #[default]
    F32,
    /// Linear weights stored as f16 (needs the adapter's `SHADER_F16`), widened to f32 as they are read: f32
    /// arithmetic. A layer with a weight beyond f16's range (|w| > 65504, which f16 would turn into infinity)
    /// stays f32 and is listed in [`GpuWeights::kept_f32`].
    F16Weights,
    /// The tensor path: [`F16Weights`](Self::F16Weights), and where the device has cooperative matrices every GEMM
    /// (linear layers, convolutions, attention's two products) runs on the tensor kernels (`MatmulKernel::Coop`,
    /// `KernelChoice::at_precision`), its operands rounded to f16 as they are staged, the products summed in f32, the
    /// values between ops f32. Elsewhere, linear layers on the GPUs' kernel (`MatmulKernel::Tiled`) round their
    /// inputs to f16 as they stage them (`shaders/tiles.wgsl`) and other kernels compute as under `F16Weights`.
    /// Values beyond f16's range become infinite.
    F16Activations,
}

impl Precision {
    /// Every precision.
    pub const ALL: [Precision; 3] = [Precision::F32, Precision::F16Weights, Precision::F16Activations];

    /// The name `--precision` takes and the benchmark's records use.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F16Weights => "f16",
            Precision::F16Activations => "f16-act",
        }
    }

    /// The precision called `name` ([`name`](Self::name)).
    pub fn from_name(name: &str) -> Option<Precision> {
        Precision::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Whether linear weights are stored as f16.
    pub fn f16_weights(self) -> bool {
        self != Precision::F32
    }
}

/// Options for putting a model on the GPU.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    pub precision: Precision,
}

/// A linear layer whose weights stay f32 under an f16 [`Precision`], and why.
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
    /// Linear layers kept in f32 under an f16 [`Precision`] because a weight is beyond f16's range.
    pub kept_f32: Vec<KeptF32>,
    /// Whether plans over these weights stage linear layers' inputs as f16 ([`Precision::F16Activations`]).
    pub f16_activations: bool,
}

impl WeightSet {
    /// Puts every prepared weight on the GPU in the layout its kernel reads.
    pub fn upload(&self, gpu: &Gpu, options: &LoadOptions) -> Result<GpuWeights> {
        let f16_weights = options.precision.f16_weights();
        if f16_weights && !gpu.features.contains(wgpu::Features::SHADER_F16) {
            return Err(EngineError::Request(format!(
                "precision {}: f16 weights need shader-f16, which {} does not have (use f32)",
                options.precision.name(),
                gpu.info.name
            )));
        }
        let mut weights = GpuWeights {
            tensors: Vec::with_capacity(self.prepared.len()),
            bytes: 0,
            kept_f32: Vec::new(),
            f16_activations: options.precision == Precision::F16Activations,
        };
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
                    if !f16_weights {
                        gpu.upload(&p.name, rows, cols, &data)?
                    } else if half::f16::from_f32(max_abs).is_finite() {
                        gpu.upload_f16(&p.name, rows, cols, &data)?
                    } else {
                        weights.kept_f32.push(KeptF32 { tensor: p.name.clone(), max_abs });
                        gpu.upload(&p.name, rows, cols, &data)?
                    }
                }
            };
            weights.bytes += tensor.bytes();
            weights.tensors.push(tensor);
        }
        Ok(weights)
    }
}
