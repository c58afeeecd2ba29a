//! raypatch-model: what a model and a scene are, independent of the GPU: the config (official keys and
//! defaults), the official state_dict names and shapes, and the safetensors model and scene files.

pub mod checkpoint;
pub mod config;
pub mod error;
pub mod files;
pub mod layout;
pub mod official;
pub mod patch_size;
pub mod pinhole;
pub mod rays;
pub mod tensor_file;
pub mod views;
pub mod weights;

pub use config::RayKind;
pub use config::{
    DecoderConfig, DefineConfig, DefineDecoderConfig, DefineEncoderConfig, EncoderConfig, Family, FamilyConfig,
    ModelConfig, Octaves, OsrtConfig, RayFeatures, RayPatchConfig, RayPredictorConfig, SlotAttentionConfig,
    SlotMixerConfig, SrtConfig, FAMILY_BASES,
};
pub use error::ModelError;
pub use patch_size::PatchSize;
pub use tensor_file::{HostTensor, TensorFile, MODEL_FORMAT};
pub use views::{load_scene, InputViews, RaySource, SceneFile, TargetGrid, TargetRays, TargetViews};
pub use weights::{load_model, LoadedModel};
