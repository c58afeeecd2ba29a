//! raypatch-model: what a model and a scene are, independent of the GPU.

pub mod error;
pub use error::ModelError;
