//! Loading a model file: the config from the metadata, and the tensors, fetched by name and shape by whoever
//! builds the model (the engine's module tree declares each weight where it fetches it; see
//! `raypatch_engine::nn::Vars`). A tensor nobody fetched means the file was made for another
//! architecture or config: [`LoadedModel::check_all_fetched`].

use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::tensor_file::{HostTensor, TensorFile, MODEL_FORMAT};

/// A model file with a valid config; its tensors are checked as they are fetched.
#[derive(Debug)]
pub struct LoadedModel {
    pub path: String,
    pub config: ModelConfig,
    pub metadata: HashMap<String, String>,
    file: TensorFile,
}

impl LoadedModel {
    /// The F32 weight `key` of shape `shape`, read now: an error naming the file and the tensor when it is
    /// missing, has another shape or dtype, or holds NaN or infinity.
    pub fn weight(&self, key: &str, shape: &[usize]) -> Result<HostTensor, ModelError> {
        self.file.f32_shaped(key, shape)
    }

    /// The shape and bytes of the tensor `key`, if the file has it (nothing is read).
    pub fn tensor_size(&self, key: &str) -> Option<(&[usize], u64)> {
        Some((self.file.shape(key)?, self.file.tensor_bytes(key)?))
    }

    /// Checks that every tensor of the file but BatchNorm's `num_batches_tracked` is in `fetched`.
    pub fn check_all_fetched(&self, fetched: &BTreeSet<String>) -> Result<(), ModelError> {
        match self.file.keys().find(|key| !fetched.contains(*key) && !key.ends_with(".num_batches_tracked")) {
            Some(key) => Err(ModelError::Unexpected {
                path: self.path.clone(),
                key: key.to_string(),
                found: self.file.shape(key).unwrap_or_default().to_vec(),
            }),
            None => Ok(()),
        }
    }

    /// The model file's bytes where they are in memory: for a checkpoint, the model file made of it.
    pub fn file_bytes(&self) -> Option<&[u8]> {
        self.file.memory_bytes()
    }

    /// The number of tensors in the file.
    pub fn tensor_count(&self) -> usize {
        self.file.keys().count()
    }

    /// Total number of parameters (BatchNorm running statistics included, `num_batches_tracked` not).
    pub fn parameter_count(&self) -> usize {
        self.file
            .keys()
            .filter(|key| !key.ends_with(".num_batches_tracked"))
            .filter_map(|key| self.file.shape(key))
            .map(|shape| shape.iter().product::<usize>())
            .sum()
    }
}

/// Loads a model file: a raypatch model .safetensors file, or an official Lightning checkpoint (told apart by
/// their first bytes, not their names), read as the model file the Python converter makes of it.
pub fn load_model(path: impl AsRef<Path>) -> Result<LoadedModel, ModelError> {
    let path = path.as_ref();
    match crate::checkpoint::open_if_checkpoint(path)? {
        Some(file) => model_from_file(file),
        None => model_from_file(TensorFile::open_as(path, MODEL_FILE)?),
    }
}

/// [`load_model`] of a file's bytes; `name` names it in messages.
pub fn model_from_bytes(name: &str, bytes: &[u8]) -> Result<LoadedModel, ModelError> {
    match crate::checkpoint::parse_if_checkpoint(name, bytes)? {
        Some(file) => model_from_file(file),
        None => model_from_file(TensorFile::parse_as(name, bytes, MODEL_FILE)?),
    }
}

/// What a model file must be, for messages.
const MODEL_FILE: &str = "a model .safetensors file (docs/FORMATS.md)";

/// Reads the config of a parsed model file (its tensors are checked when the model is built).
pub fn model_from_file(file: TensorFile) -> Result<LoadedModel, ModelError> {
    let path = file.path.clone();
    let config_err = |reason: String| ModelError::Config { path: path.clone(), reason };
    if !file.metadata.contains_key("config") && file.contains("input_images") {
        return Err(config_err("this is a scene file, expected a model .safetensors file (docs/FORMATS.md)".into()));
    }
    if let Some(format) = file.metadata.get("format") {
        if format != MODEL_FORMAT {
            return Err(config_err(format!("metadata format is {format:?}, expected {MODEL_FORMAT:?}")));
        }
    }
    let text = file.metadata.get("config").ok_or_else(|| {
        config_err(
            "no `config` entry in the safetensors metadata (convert official checkpoints with tools/conversion/convert_checkpoint.py)"
                .into(),
        )
    })?;
    let raw =
        serde_json::from_str(text).map_err(|e| config_err(format!("`config` metadata is not valid JSON: {e}")))?;
    let config = ModelConfig::from_value(&path, raw)?;
    config.check_counts(&path, file.keys().count())?;
    Ok(LoadedModel { path, config, metadata: file.metadata.clone(), file })
}
