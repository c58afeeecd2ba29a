use thiserror::Error;

#[derive(Debug, Error)]
pub enum EngineError {
    #[error("no GPU adapter: {0}")]
    NoAdapter(String),
    #[error("GPU device error: {0}")]
    Device(String),
    #[error("{what} needs {bytes} bytes in one buffer, more than the {max} bytes one buffer may have on this engine")]
    TooLarge { what: String, bytes: u64, max: u64 },
    #[error(transparent)]
    Model(#[from] raypatch_model::ModelError),
    #[error("{what}: values first become NaN or infinity in op `{op}` (tensor `{tensor}`): the model's weights or the inputs overflow float32 there")]
    NonFinite { what: String, op: String, tensor: String },
    #[error("invalid request: {0}")]
    Request(String),
}

pub type Result<T> = std::result::Result<T, EngineError>;
