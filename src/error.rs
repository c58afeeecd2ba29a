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
    /// Camera input refused before any work (`crate::input`): a pose that is not finite and rigid, an axis
    /// convention's name, an image size the model's patch size does not divide, a frame count out of range.
    #[error("{0}")]
    Input(String),
}

/// Whose fault an [`Error`](enum@Error) is: what each surface maps to its own answer, in one table each (the
/// CLI's exit code, the viewer's HTTP status, Python's exception class).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// What the caller asked for: a size, pose, camera, flag, option or request the engine cannot take, or one
    /// too large for this device's buffers or float32.
    Input,
    /// A model, scene, image or camera file that is missing, unreadable or malformed, or an output that cannot
    /// be written.
    File,
    /// The device: no adapter, a device lost or failing, out of memory.
    Device,
    /// A broken invariant of raypatch itself: a bug.
    Internal,
}

/// The exit code of a process that `error` stopped, from whose fault it is: the kind of the first
/// [`Error`](enum@Error) among its causes. 2 for what was asked or given (bad input, a missing or malformed file;
/// also a surface's own refusals, which carry no raypatch error), 3 for the device, 70 (EX_SOFTWARE) for a bug.
/// render-frame and its viewer exit with it.
pub fn exit_code(error: &(dyn std::error::Error + 'static)) -> u8 {
    match causes(error).find_map(|c| c.downcast_ref::<Error>()).map(Error::kind) {
        None | Some(ErrorKind::Input | ErrorKind::File) => 2,
        Some(ErrorKind::Device) => 3,
        Some(ErrorKind::Internal) => 70,
    }
}

/// `error` and its causes on one bounded line, leaving out causes that an outer message already quotes: what a
/// process prints before it exits with [`exit_code`].
pub fn error_line(error: &(dyn std::error::Error + 'static)) -> String {
    let mut line = String::new();
    for cause in causes(error) {
        let text = cause.to_string().replace('\n', " ");
        if !line.contains(&text) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&text);
        }
    }
    raypatch_model::error::one_line(&line)
}

fn causes<'e>(
    error: &'e (dyn std::error::Error + 'static),
) -> impl Iterator<Item = &'e (dyn std::error::Error + 'static)> {
    std::iter::successors(Some(error), |e| e.source())
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
    /// Whose fault this error is.
    ///
    /// ```
    /// use raypatch::{Engine, EngineOptions, ErrorKind};
    /// # let engine = Engine::new(EngineOptions::default())?;
    /// assert_eq!(engine.load("no/such/model.safetensors").err().map(|e| e.kind()), Some(ErrorKind::File));
    /// assert_eq!("blender".parse::<raypatch::CameraAxes>().unwrap_err().kind(), ErrorKind::Input);
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn kind(&self) -> ErrorKind {
        use raypatch_engine::EngineError as E;
        match self {
            Error::Model(_) | Error::Io { .. } | Error::Output { .. } | Error::Image { .. } | Error::Cameras { .. } => {
                ErrorKind::File
            }
            Error::Camera(_) | Error::Views(_) | Error::Metrics(_) | Error::Input(_) => ErrorKind::Input,
            Error::Engine(e) => match e {
                E::Model(_) => ErrorKind::File,
                // Values that overflow float32 are the weights' or the inputs' (hardening: render-frame exits 2).
                E::AdapterNotFound(_) | E::TooLarge { .. } | E::NonFinite { .. } | E::Request(_) => ErrorKind::Input,
                E::NoAdapter(_) | E::Device(_) | E::OutOfMemory(_) => ErrorKind::Device,
                E::Bug(_) => ErrorKind::Internal,
            },
        }
    }

    pub(crate) fn io(path: &std::path::Path, action: &'static str, source: std::io::Error) -> Error {
        Error::Io { path: path.display().to_string(), action, source }
    }
}
