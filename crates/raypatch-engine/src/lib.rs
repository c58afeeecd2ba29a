//! raypatch-engine: WGSL kernels, the plan/executor, `nn` modules, the model families and the scene core.
//!
//! Data path: safetensors weights (`raypatch-model`) → a family's module tree (`models`, built from `nn`
//! modules that fetch their weights by official name) → GPU weights → per scene an encode plan, per
//! (view count, computed size, outputs) a render plan (`scene`, recorded through `graph` into `plan`) →
//! kernels (`kernels`, one WGSL file each in `shaders/`) → frame (`frame`).

// The blocking calls of the native API (a browser has only the async ones).
#[cfg(not(target_family = "wasm"))]
mod blocking;
pub mod device;
pub mod encoded;
pub mod error;
pub mod frame;
pub mod gpu;
pub mod graph;
pub mod kernels;
pub mod model;
pub mod models;
pub mod nn;
pub mod pipeline_cache;
pub mod plan;
mod render_io;
pub mod tensor;
pub mod weights;

#[cfg(not(target_family = "wasm"))]
pub use blocking::Renders;
pub use device::MatmulKernel;
pub use encoded::{EncodedScene, OpTimes};
pub use error::{EngineError, Result};
pub use frame::{Frame, Output, OutputValues, Outputs, Region, RenderStats, Request};
pub use gpu::{AdapterChoice, Gpu, GpuOptions};
pub use model::Model;
pub use pipeline_cache::{PipelineCacheDir, PipelineCacheStatus};
pub use tensor::GpuTensor;
pub use weights::{KeptF32, LoadOptions, Precision};
/// The wgpu this engine is built on (for its types in the public API, e.g. `Gpu::features`).
pub use wgpu;
