//! Output files, written so that nothing is lost: every output is checked before any is written, all are
//! written to temporaries in their own folders, and only when every write succeeded are they renamed into
//! place. A path that exists must be a regular file: a symlink, FIFO, device or folder there is refused,
//! never replaced. Temporaries are unique per process; ones left by a killed run are removed later.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use raypatch_model::files::file_kind;

use crate::error::{Error, Result};

/// Marks our temporaries: `.NAME.raypatch-PID-N.tmp`.
const TEMP_MARK: &str = ".raypatch-";

/// Checks that `path` can take an output: its folder exists, and if something is at `path` it is a regular
/// file (not followed if it is a symlink).
pub fn check_output_path(path: &Path) -> Result<()> {
    let refuse = |reason: String| Error::io(path, "cannot write", std::io::Error::other(reason));
    if path.file_name().is_none() {
        return Err(refuse("expected a file name".into()));
    }
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        if !meta.is_file() {
            return Err(refuse(format!("is {}; only regular files are replaced", file_kind(&meta))));
        }
    }
    let folder = folder_of(path);
    if !folder.is_dir() {
        return Err(refuse(format!("folder {} does not exist", folder.display())));
    }
    Ok(())
}

/// Writes `bytes` to `path` through a unique temporary file in the same folder and a rename, so that no
/// partial file is left behind. See [`write_all_atomic`].
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_all_atomic(&[(path, bytes)])
}

/// Writes every file or none: checks all paths ([`check_output_path`]), writes each to a temporary, and
/// renames them into place only when all were written. On an error the temporaries are removed and no
/// existing file has been touched (short of a rename failing after the checks, which a folder that accepted
/// the temporary does not do).
pub fn write_all_atomic(files: &[(&Path, &[u8])]) -> Result<()> {
    for (path, _) in files {
        check_output_path(path)?;
    }
    let mut folders: Vec<&Path> = files.iter().map(|(p, _)| folder_of(p)).collect();
    folders.dedup();
    for folder in &folders {
        remove_stale_temporaries(folder);
    }
    let mut temporaries: Vec<PathBuf> = Vec::with_capacity(files.len());
    let written = files.iter().try_for_each(|(path, bytes)| {
        let tmp = temporary_for(path);
        // create_new: never follows or reuses anything already at the temporary's name.
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp);
        let result = file.and_then(|mut f| f.write_all(bytes).and_then(|()| f.sync_data()));
        if file_exists(&tmp) {
            temporaries.push(tmp);
        }
        result.map_err(|e| Error::io(path, "cannot write", e))
    });
    let renamed = written.and_then(|()| {
        for ((path, _), tmp) in files.iter().zip(&temporaries) {
            check_output_path(path)?;
            std::fs::rename(tmp, path).map_err(|e| Error::io(path, "cannot write", e))?;
        }
        Ok(())
    });
    if renamed.is_err() {
        for tmp in &temporaries {
            let _ = std::fs::remove_file(tmp);
        }
    }
    renamed
}

fn file_exists(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok()
}

/// The folder a path's file is in: its parent, or `.` for a bare file name.
pub fn folder_of(path: &Path) -> &Path {
    path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

fn temporary_for(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}{TEMP_MARK}{}-{n}.tmp", std::process::id()))
}

/// The process id in one of our temporaries' names.
fn temporary_owner(name: &str) -> Option<u32> {
    let rest = name.strip_suffix(".tmp")?;
    let (_, tail) = rest.rsplit_once(TEMP_MARK)?;
    let (pid, n) = tail.split_once('-')?;
    n.parse::<u64>().ok()?;
    pid.parse().ok()
}

/// Removes temporaries of ours in `folder` whose process is gone (a run that was killed); where process ids
/// cannot be checked (no /proc), those older than a day.
fn remove_stale_temporaries(folder: &Path) {
    let Ok(entries) = std::fs::read_dir(folder) else { return };
    let proc = Path::new("/proc/self").exists();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = temporary_owner(&name) else { continue };
        let Ok(meta) = std::fs::symlink_metadata(entry.path()) else { continue };
        let stale = if proc {
            pid != std::process::id() && !Path::new("/proc").join(pid.to_string()).exists()
        } else {
            meta.modified().ok().and_then(|t| t.elapsed().ok()).is_some_and(|age| age.as_secs() > 24 * 3600)
        };
        if stale && meta.is_file() {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("raypatch-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn all_or_nothing_and_only_regular_files_replaced() {
        let dir = temp_dir("all");
        let (keep, blocked) = (dir.join("keep.png"), dir.join("raw.safetensors"));
        std::fs::write(&keep, b"work").unwrap();
        std::fs::create_dir(&blocked).unwrap();
        let err = write_all_atomic(&[(&keep, b"new"), (&blocked, b"raw")]).unwrap_err().to_string();
        assert!(err.contains("raw.safetensors") && err.contains("a folder"), "{err}");
        assert_eq!(std::fs::read(&keep).unwrap(), b"work");
        #[cfg(unix)]
        {
            let link = dir.join("link.png");
            std::os::unix::fs::symlink(&keep, &link).unwrap();
            let err = write_atomic(&link, b"x").unwrap_err().to_string();
            assert!(err.contains("symbolic link"), "{err}");
            assert_eq!(std::fs::read(&keep).unwrap(), b"work");
        }
        write_all_atomic(&[(&keep, b"new"), (&dir.join("b.png"), b"b")]).unwrap();
        assert_eq!(std::fs::read(&keep).unwrap(), b"new");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name()).collect();
        assert!(left.iter().all(|n| !n.to_string_lossy().ends_with(".tmp")), "{left:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn stale_temporaries_of_dead_runs_are_removed() {
        let dir = temp_dir("stale");
        // Process ids are below 2^22 on Linux: this one cannot be running.
        let stale = dir.join(format!(".a.png{TEMP_MARK}4294967294-0.tmp"));
        let other = dir.join(".a.png.tmp");
        std::fs::write(&stale, b"x").unwrap();
        std::fs::write(&other, b"x").unwrap();
        write_atomic(&dir.join("a.png"), b"png").unwrap();
        if Path::new("/proc/self").exists() {
            assert!(!stale.exists());
        }
        assert!(other.exists(), "not ours: kept");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
