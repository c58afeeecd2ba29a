//! Loading a model file: the config from the metadata, and every official tensor checked by name, dtype
//! and shape against what that config implies.

use std::collections::HashMap;
use std::path::Path;

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::tensor_file::{HostTensor, TensorFile};

/// The metadata `format` value of model files.
pub const MODEL_FORMAT: &str = "raypatch-model/1";

/// A model file, validated: its config and its weights under their official names.
#[derive(Debug)]
pub struct LoadedModel {
    pub path: String,
    pub config: ModelConfig,
    pub metadata: HashMap<String, String>,
    weights: HashMap<String, HostTensor>,
}

impl LoadedModel {
    /// The weight `key`. Every key of [`ModelConfig::expected_tensors`] is present after loading.
    pub fn weight(&self, key: &str) -> &HostTensor {
        self.weights.get(key).unwrap_or_else(|| panic!("weight {key} is not part of this model"))
    }

    /// Total number of parameters (BatchNorm running statistics included).
    pub fn parameter_count(&self) -> usize {
        self.weights.values().map(|t| t.data.len()).sum()
    }
}

pub fn load_model(path: impl AsRef<Path>) -> Result<LoadedModel, ModelError> {
    model_from_file(TensorFile::open_as(path.as_ref(), "a model .safetensors file (docs/FORMATS.md)")?)
}

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
            "no `config` entry in the safetensors metadata (convert official checkpoints with tools/convert_checkpoint.py)"
                .into(),
        )
    })?;
    let raw =
        serde_json::from_str(text).map_err(|e| config_err(format!("`config` metadata is not valid JSON: {e}")))?;
    let config = ModelConfig::from_value(&path, raw)?;
    config.check_counts(&path, file.keys().count())?;

    let expected = config.expected_tensors();
    let mut weights = HashMap::with_capacity(expected.len());
    for (key, shape) in &expected {
        weights.insert(key.clone(), file.f32_shaped(key, shape)?);
    }
    // Anything else in the file means it was made for another architecture or config.
    for key in file.keys() {
        if !weights.contains_key(key) && !key.ends_with(".num_batches_tracked") {
            return Err(ModelError::Unexpected {
                path: path.clone(),
                key: key.to_string(),
                found: file.shape(key).unwrap_or_default().to_vec(),
            });
        }
    }
    Ok(LoadedModel { path, config, metadata: file.metadata, weights })
}
