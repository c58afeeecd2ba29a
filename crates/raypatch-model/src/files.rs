//! The one checked way in for untrusted files: every model, scene, frame image, pose and cache is opened
//! through [`open_regular`] (whole small files read by [`read_regular`], tensor files one tensor at a time),
//! and every file a scene folder names is resolved through [`resolve_inside`].
//!
//! - Only regular files are read. A FIFO, socket or device is refused before it is opened for reading (a
//!   FIFO would block forever, `/dev/zero` never ends); the open itself does not block, and the opened
//!   handle is checked again, so swapping the path between the check and the open gains nothing.
//! - Never more than the file's size is read, and never more than the caller's limit.
//! - A file named by a scene folder must resolve, symlinks followed, to a file inside that folder. The error
//!   for a name that leaves the folder does not say whether anything exists there.

use std::io::Read;
use std::path::{Component, Path, PathBuf};

use crate::error::Quoted;

/// Why a file could not be read, as one phrase (the caller names the file).
#[derive(Debug)]
pub enum ReadError {
    /// The operating system's error (missing, no permission, ...).
    Io(std::io::Error),
    /// The path exists but is not a regular file: what it is instead.
    NotRegular(&'static str),
    /// The file is larger than the caller accepts.
    TooLarge { bytes: u64, max: u64 },
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReadError::Io(e) => write!(f, "{e}"),
            ReadError::NotRegular(kind) => write!(f, "is {kind}, not a regular file"),
            ReadError::TooLarge { bytes, max } => write!(f, "is {bytes} bytes, more than the {max} bytes accepted"),
        }
    }
}

impl std::error::Error for ReadError {}

impl From<ReadError> for std::io::Error {
    fn from(e: ReadError) -> std::io::Error {
        match e {
            ReadError::Io(e) => e,
            other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
        }
    }
}

/// What a non-regular file is, in words.
pub fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    let t = meta.file_type();
    if t.is_dir() {
        return "a folder";
    }
    if t.is_symlink() {
        return "a symbolic link";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_socket() {
            return "a socket";
        }
        if t.is_block_device() || t.is_char_device() {
            return "a device";
        }
    }
    "not a regular file"
}

/// Opens a regular file (symlinks followed) for reading, without blocking: the file and its length.
pub fn open_regular(path: &Path) -> Result<(std::fs::File, u64), ReadError> {
    let meta = std::fs::metadata(path).map_err(ReadError::Io)?;
    if !meta.is_file() {
        return Err(ReadError::NotRegular(file_kind(&meta)));
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // A FIFO swapped in after the check must not block the open.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(ReadError::Io)?;
    let meta = file.metadata().map_err(ReadError::Io)?;
    if !meta.is_file() {
        return Err(ReadError::NotRegular(file_kind(&meta)));
    }
    Ok((file, meta.len()))
}

/// Reads a whole regular file (symlinks followed) of at most `max_bytes`.
pub fn read_regular(path: &Path, max_bytes: u64) -> Result<Vec<u8>, ReadError> {
    let (file, len) = open_regular(path)?;
    within(len, max_bytes)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(len).read_to_end(&mut bytes).map_err(ReadError::Io)?;
    Ok(bytes)
}

/// Like [`read_regular`], as UTF-8 text.
pub fn read_regular_text(path: &Path, max_bytes: u64) -> Result<String, ReadError> {
    let bytes = read_regular(path, max_bytes)?;
    as_text(&bytes)?;
    Ok(String::from_utf8(bytes).expect("checked as UTF-8"))
}

/// A file's length `len` if it is at most `max_bytes` (files read whole, from disk or given as bytes).
pub fn within(len: u64, max_bytes: u64) -> Result<(), ReadError> {
    if len > max_bytes {
        return Err(ReadError::TooLarge { bytes: len, max: max_bytes });
    }
    Ok(())
}

/// A whole file's bytes as UTF-8 text.
pub fn as_text(bytes: &[u8]) -> Result<&str, ReadError> {
    std::str::from_utf8(bytes)
        .map_err(|_| ReadError::Io(std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text")))
}

/// Whether `name` (as written in a scene folder's JSON) is a relative path without `..`: the names that may stand
/// for a file inside the folder. Why not, where it is not.
pub fn check_relative(name: &str) -> Result<&Path, String> {
    let relative = Path::new(name);
    if name.is_empty() || relative.components().any(|c| !matches!(c, Component::Normal(_) | Component::CurDir)) {
        return Err(format!(
            "{:?} is not a relative path inside the scene folder (no `..`, no absolute path)",
            Quoted(name)
        ));
    }
    Ok(relative)
}

/// The file `name` (as written in a scene folder's JSON) inside `dir`: a relative path without `..` that
/// resolves, symlinks followed, to a regular file inside `dir`. Returns the resolved path, or why not.
pub fn resolve_inside(dir: &Path, name: &str) -> Result<PathBuf, String> {
    let quoted = Quoted(name);
    let outside = || format!("{quoted:?} does not name a regular file inside the scene folder");
    let relative = check_relative(name)?;
    let root = dir.canonicalize().map_err(|e| format!("{}: {e}", dir.display()))?;
    let joined = root.join(relative);
    if std::fs::symlink_metadata(&joined).is_err() {
        return Err(format!("{quoted:?}: no such file in the scene folder"));
    }
    // Something is there: only a regular file inside the folder is acceptable, and every other case gets
    // the same words (a dangling link and a link to an outside file must not be told apart).
    let resolved = joined.canonicalize().map_err(|_| outside())?;
    if !resolved.starts_with(&root) || !std::fs::metadata(&resolved).is_ok_and(|m| m.is_file()) {
        return Err(outside());
    }
    Ok(resolved)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("raypatch-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn names_must_stay_inside_the_folder() {
        let dir = temp_dir("inside");
        std::fs::create_dir(dir.join("scene")).unwrap();
        std::fs::write(dir.join("scene/a.png"), b"x").unwrap();
        std::fs::write(dir.join("secret.png"), b"x").unwrap();
        let scene = dir.join("scene");
        assert!(resolve_inside(&scene, "a.png").is_ok());
        assert!(resolve_inside(&scene, "./a.png").is_ok());
        for bad in ["../secret.png", "/etc/passwd", "", "sub/../../secret.png"] {
            assert!(resolve_inside(&scene, bad).unwrap_err().contains("not a relative path inside"), "{bad}");
        }
        assert!(resolve_inside(&scene, "b.png").unwrap_err().contains("no such file"));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(dir.join("secret.png"), scene.join("link.png")).unwrap();
            std::os::unix::fs::symlink(dir.join("absent.png"), scene.join("dangling.png")).unwrap();
            let (existing, dangling) =
                (resolve_inside(&scene, "link.png").unwrap_err(), resolve_inside(&scene, "dangling.png").unwrap_err());
            // The same words whether or not the outside target exists.
            assert_eq!(existing.replace("link", "X"), dangling.replace("dangling", "X"));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_regular_files_are_read_and_never_past_the_limit() {
        let dir = temp_dir("regular");
        std::fs::write(dir.join("f"), b"12345").unwrap();
        assert_eq!(read_regular(&dir.join("f"), 5).unwrap(), b"12345");
        assert!(matches!(read_regular(&dir.join("f"), 4), Err(ReadError::TooLarge { bytes: 5, max: 4 })));
        assert!(matches!(read_regular(&dir, 100), Err(ReadError::NotRegular("a folder"))));
        #[cfg(unix)]
        {
            assert!(matches!(read_regular(Path::new("/dev/zero"), 100), Err(ReadError::NotRegular("a device"))));
            let fifo = dir.join("fifo");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            assert!(matches!(read_regular(&fifo, 100), Err(ReadError::NotRegular("a FIFO"))));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
