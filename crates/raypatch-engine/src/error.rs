use thiserror::Error;

/// What the engine refuses or fails at. The variants say whose fault it is (the API's `Error::kind` reads them):
/// the device's (`NoAdapter`, `Device`, `OutOfMemory`), the request's (`AdapterNotFound`, `TooLarge`,
/// `NonFinite`, `Request`), a file's (`Model`), or the engine's own (`Bug`).
#[derive(Debug, Error)]
pub enum EngineError {
    #[error("no GPU adapter: {0}")]
    NoAdapter(String),
    /// No adapter has the name asked for.
    #[error("no GPU adapter: {0}")]
    AdapterNotFound(String),
    #[error("GPU device error: {0}")]
    Device(String),
    /// More memory than the host or the device has free.
    #[error("out of memory: {0}")]
    OutOfMemory(String),
    #[error("{what} needs {bytes} bytes in one buffer, more than the {max} bytes one buffer may have on this engine")]
    TooLarge { what: String, bytes: u64, max: u64 },
    #[error(transparent)]
    Model(#[from] raypatch_model::ModelError),
    #[error("{what}: values first become NaN or infinity in op `{op}` (tensor `{tensor}`): the model's weights or the inputs overflow float32 there")]
    NonFinite { what: String, op: String, tensor: String },
    #[error("invalid request: {0}")]
    Request(String),
    /// An invariant of the engine broken: a bug.
    #[error("internal error: {0}")]
    Bug(String),
}

pub type Result<T> = std::result::Result<T, EngineError>;
