//! The one error type of the API.

use thiserror::Error;

/// Everything that can go wrong, each with a one-line message that names the file, tensor, camera or request
/// field at fault and what was expected.
///
/// ```
/// use raypatch::{Engine, EngineOptions, Error};
/// # let engine = Engine::new(EngineOptions::default())?;
/// match engine.load("no/such/model.safetensors") {
///     Err(Error::Model(e)) => assert!(e.to_string().starts_with("no/such/model.safetensors: cannot read")),
///     other => panic!("expected a file error, got {:?}", other.err()),
/// }
/// # Ok::<(), raypatch::Error>(())
/// ```
#[derive(Debug, Error)]
pub enum Error {
    /// A model or scene safetensors file is missing, malformed, or holds wrong tensors.
    #[error(transparent)]
    Model(#[from] raypatch_model::ModelError),
    /// The GPU side: no adapter, a device error, a request the model cannot serve.
    #[error(transparent)]
    Engine(raypatch_engine::EngineError),
    /// A file that could not be read or written.
    #[error("{path}: {action}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// What was being done, e.g. "cannot read".
        action: &'static str,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// An output that cannot be written where it was asked (checked before anything is written): a path that is
    /// not a regular file or whose folder is missing, an input, or the same file as another output.
    #[error("{path}: {reason}")]
    Output {
        /// The output, with the flag or argument that named it where there is one (`--out x.png`).
        path: String,
        /// What is wrong, e.g. "would overwrite the input given by --model".
        reason: String,
    },
    /// An image that could not be decoded or encoded.
    #[error("{path}: {reason}")]
    Image {
        /// The image file (`image` for images built in memory).
        path: String,
        /// What is wrong.
        reason: String,
    },
    /// A `transforms.json` or pose file that does not describe valid cameras.
    #[error("{path}: {reason}")]
    Cameras {
        /// The JSON file.
        path: String,
        /// Which frame or key is wrong, and how.
        reason: String,
    },
    /// A camera that cannot be built: non-finite numbers, a rotation that is not orthonormal, a zero size.
    #[error("camera: {0}")]
    Camera(String),
    /// Input views that cannot be encoded together: none, different sizes, values outside [0, 1].
    #[error("input views: {0}")]
    Views(String),
    /// Images that cannot be compared (metrics).
    #[error("metrics: {0}")]
    Metrics(String),
}

/// `Result` with [`Error`](enum@Error).
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// File errors the engine passes through stay [`Error::Model`].
impl From<raypatch_engine::EngineError> for Error {
    fn from(e: raypatch_engine::EngineError) -> Error {
        match e {
            raypatch_engine::EngineError::Model(m) => Error::Model(m),
            other => Error::Engine(other),
        }
    }
}

impl Error {
    pub(crate) fn io(path: &std::path::Path, action: &'static str, source: std::io::Error) -> Error {
        Error::Io { path: path.display().to_string(), action, source }
    }
}
