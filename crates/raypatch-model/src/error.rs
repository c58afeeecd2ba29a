use thiserror::Error;

/// Everything that can be wrong with a model or scene file. Each message names the file and the tensor
/// or key, what was expected and what was found.
#[derive(Debug, Error)]
pub enum ModelError {
    #[error("{path}: cannot read: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a valid safetensors file: {reason}")]
    Format { path: String, reason: String },
    #[error("{path}: checkpoint: {reason}")]
    Checkpoint { path: String, reason: String },
    #[error("{path}: config: {reason}")]
    Config { path: String, reason: String },
    #[error("{path}: missing tensor `{key}` (expected shape {expected:?})")]
    Missing { path: String, key: String, expected: Vec<usize> },
    #[error("{path}: unexpected tensor `{key}` with shape {found:?} (not part of this model)")]
    Unexpected { path: String, key: String, found: Vec<usize> },
    #[error("{path}: tensor `{key}` has shape {found:?}, expected {expected:?}")]
    Shape { path: String, key: String, expected: Vec<usize>, found: Vec<usize> },
    #[error("{path}: tensor `{key}` has dtype {found}, expected F32")]
    Dtype { path: String, key: String, found: String },
    #[error("{path}: tensor `{key}`: {reason}")]
    Value { path: String, key: String, reason: String },
}
