//! raypatch-engine: WGSL kernels, the plan/executor, and the SRT / RP-SRT graphs.
//!
//! Data path: safetensors weights (`raypatch-model`) → GPU weights (`model`) → a [`plan::Plan`] per
//! (model, input views, target size, outputs) → kernels (`kernels`, one WGSL file each in `shaders/`) → frame.

pub mod error;
pub mod gpu;
pub mod kernels;
pub mod plan;
pub mod reference;
pub mod srt;
pub mod tensor;
pub mod weights;

pub use error::{EngineError, Result};
pub use gpu::{AdapterChoice, Gpu, GpuOptions};
pub use srt::{EncodedScene, Frame, Model, OpTimes, Outputs, Region, RenderStats, Request};
pub use tensor::GpuTensor;
/// The wgpu this engine is built on (for its types in the public API, e.g. `Gpu::features`).
pub use wgpu;
