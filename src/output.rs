//! Output files, written so that nothing is lost: every output is checked before any is written, all are
//! written to temporaries in their own folders, and only when every write succeeded are they moved into
//! place, all or none: an existing file is first moved aside, and when any move fails every move done is
//! undone. A path that exists must be a regular file: a symlink, FIFO, device or folder there is refused,
//! never replaced. Temporaries are unique per process; ones left by a killed run are removed later.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use raypatch_model::files::file_kind;

use crate::error::{Error, Result};

/// Marks our temporaries, `.NAME.raypatch-PID-N.tmp`, and the files moved aside while outputs are moved into
/// place, `.NAME.raypatch-PID-N.bak`.
const TEMP_MARK: &str = ".raypatch-";

/// The longest file name most file systems take (bytes).
const MAX_NAME_BYTES: usize = 255;

/// Checks that `path` can take an output: its folder exists, and if something is at `path` it is a regular
/// file (not followed if it is a symlink).
pub fn check_output_path(path: &Path) -> Result<()> {
    let refuse = |reason: String| Error::io(path, "cannot write", std::io::Error::other(reason));
    let Some(name) = path.file_name() else {
        return Err(refuse("expected a file name".into()));
    };
    if name.len() > MAX_NAME_BYTES {
        return Err(refuse(format!(
            "the name is {} bytes, more than the {MAX_NAME_BYTES} a file name may have",
            name.len()
        )));
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
/// moves them into place only when all were written (`move_all_into_place`). On an error the temporaries
/// are removed and every existing file is as it was.
pub fn write_all_atomic(files: &[(&Path, &[u8])]) -> Result<()> {
    for (path, _) in files {
        check_output_path(path)?;
    }
    let mut staged = Staged::default();
    for (path, bytes) in files {
        let mut file = staged.create(path)?;
        file.write_all(bytes).map_err(|e| Error::io(path, "cannot write", e))?;
    }
    staged.commit()
}

/// Outputs being written, all or none, as they are made (a video's frames stream into its file): each is a
/// temporary in its own folder until [`commit`](Self::commit) moves them all into place as
/// [`write_all_atomic`] does; dropped without a commit (an error, a panic), the temporaries are removed.
#[derive(Default)]
pub struct Staged {
    /// (temporary, destination), in the order they were created.
    files: Vec<(PathBuf, PathBuf)>,
}

impl Staged {
    /// Creates the temporary that will become `path` ([`check_output_path`] first) and opens it for writing.
    pub fn create(&mut self, path: &Path) -> Result<std::fs::File> {
        check_output_path(path)?;
        let folder = folder_of(path);
        if !self.files.iter().any(|(_, dest)| folder_of(dest) == folder) {
            remove_stale_temporaries(folder);
        }
        let tmp = temporary_for(path);
        // create_new: never follows or reuses anything already at the temporary's name.
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp);
        let file = file.map_err(|e| Error::io(path, "cannot write", e))?;
        self.files.push((tmp, path.to_path_buf()));
        Ok(file)
    }

    /// Flushes every temporary to disk and moves them all into place, all or none.
    pub fn commit(mut self) -> Result<()> {
        let files = std::mem::take(&mut self.files);
        let synced = files.iter().try_for_each(|(tmp, dest)| {
            std::fs::File::open(tmp).and_then(|f| f.sync_all()).map_err(|e| Error::io(dest, "cannot write", e))
        });
        let moves: Vec<(&Path, &Path)> = files.iter().map(|(t, d)| (t.as_path(), d.as_path())).collect();
        let placed = synced.and_then(|()| move_all_into_place(&moves));
        if placed.is_err() {
            self.files = files;
        }
        placed
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (tmp, _) in &self.files {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// One step of [`move_all_into_place`], to undo if a later one fails.
enum Moved<'a> {
    /// An existing file was moved aside to `backup`.
    Aside { dest: &'a Path, backup: PathBuf },
    /// A temporary was renamed to `dest`.
    Placed { dest: &'a Path },
}

/// Renames each `(temporary, destination)`, all or none. A destination that exists is first moved aside
/// (a rename within its folder), so that when a later rename fails (a sticky folder where another user owns
/// the file, a destination swapped for a folder) every output placed is removed and every file moved aside
/// is put back.
fn move_all_into_place(moves: &[(&Path, &Path)]) -> Result<()> {
    let mut done: Vec<Moved> = Vec::with_capacity(2 * moves.len());
    let mut result = Ok(());
    for &(tmp, dest) in moves {
        let step = (|| {
            check_output_path(dest)?;
            let cannot = |e| Error::io(dest, "cannot write", e);
            if file_exists(dest) {
                let backup = sibling(dest, "bak");
                std::fs::rename(dest, &backup).map_err(cannot)?;
                done.push(Moved::Aside { dest, backup });
            }
            std::fs::rename(tmp, dest).map_err(cannot)?;
            done.push(Moved::Placed { dest });
            Ok(())
        })();
        if let Err(e) = step {
            result = Err(e);
            break;
        }
    }
    let mut kept_aside = Vec::new();
    for step in done.iter().rev() {
        match (step, &result) {
            (Moved::Placed { dest }, Err(_)) => {
                let _ = std::fs::remove_file(dest);
            }
            (Moved::Aside { dest, backup }, Err(_)) => {
                if std::fs::rename(backup, dest).is_err() {
                    kept_aside.push(format!("{} is kept as {}", dest.display(), backup.display()));
                }
            }
            (Moved::Aside { backup, .. }, Ok(())) => {
                let _ = std::fs::remove_file(backup);
            }
            (Moved::Placed { .. }, Ok(())) => {}
        }
    }
    match result {
        Err(Error::Io { path, action, source }) if !kept_aside.is_empty() => {
            let source = std::io::Error::new(source.kind(), format!("{source}; {}", kept_aside.join(", ")));
            Err(Error::Io { path, action, source })
        }
        other => other,
    }
}

fn file_exists(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok()
}

/// The folder a path's file is in: its parent, or `.` for a bare file name.
pub fn folder_of(path: &Path) -> &Path {
    path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

fn temporary_for(path: &Path) -> PathBuf {
    sibling(path, "tmp")
}

/// A unique name in `path`'s folder, `.NAME.raypatch-PID-N.EXT`, with NAME shortened so that the whole stays
/// within [`MAX_NAME_BYTES`] (any name an output may have gets a temporary).
fn sibling(path: &Path, ext: &str) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tail = format!("{TEMP_MARK}{}-{n}.{ext}", std::process::id());
    let mut keep = name.len().min(MAX_NAME_BYTES - 1 - tail.len());
    while !name.is_char_boundary(keep) {
        keep -= 1;
    }
    path.with_file_name(format!(".{}{tail}", &name[..keep]))
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

    /// A later move that fails (its temporary gone, its destination turned into a folder) undoes the earlier
    /// ones: the file moved aside is back, the new output removed, nothing of ours left.
    #[test]
    fn a_failed_move_puts_back_what_was_replaced() {
        let dir = temp_dir("undo");
        let (keep, fresh, other) = (dir.join("keep.png"), dir.join("fresh.png"), dir.join("other.png"));
        std::fs::write(&keep, b"work").unwrap();
        std::fs::write(&other, b"other").unwrap();
        let blocked = dir.join("blocked");
        std::fs::create_dir(&blocked).unwrap();
        for (last_tmp, last_dest) in [(dir.join(".gone.tmp"), other.as_path()), (dir.join(".b.tmp"), blocked.as_path())]
        {
            let (t1, t2) = (dir.join(".t1.tmp"), dir.join(".t2.tmp"));
            std::fs::write(&t1, b"new").unwrap();
            std::fs::write(&t2, b"new").unwrap();
            if last_dest == blocked.as_path() {
                std::fs::write(&last_tmp, b"new").unwrap();
            }
            let moves = [(t1.as_path(), keep.as_path()), (t2.as_path(), fresh.as_path()), (&last_tmp, last_dest)];
            let err = move_all_into_place(&moves).unwrap_err().to_string();
            assert!(err.contains(&last_dest.display().to_string()), "{err}");
            assert_eq!(std::fs::read(&keep).unwrap(), b"work");
            assert_eq!(std::fs::read(&other).unwrap(), b"other");
            assert!(!fresh.exists());
            let ours: Vec<_> = std::fs::read_dir(&dir)
                .unwrap()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.contains(TEMP_MARK))
                .collect();
            assert!(ours.is_empty(), "{ours:?}");
            for t in [&t1, &t2, &last_tmp] {
                let _ = std::fs::remove_file(t);
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Every name an output may have gets a temporary (the temporary's name is shortened to fit), and a name
    /// no file system takes is refused before anything is written.
    #[test]
    fn long_names_are_written_or_refused_before_writing() {
        let dir = temp_dir("long");
        for len in [200, 232, 250, 255] {
            let name = format!("{}.png", "é".repeat((len - 4) / 2)) + &"x".repeat((len - 4) % 2);
            assert!(name.len() == len || name.len() == len - 1, "{}", name.len());
            let path = dir.join(&name);
            write_atomic(&path, b"png").unwrap_or_else(|e| panic!("{len}: {e}"));
            assert_eq!(std::fs::read(&path).unwrap(), b"png");
            write_atomic(&path, b"again").unwrap();
            assert_eq!(std::fs::read(&path).unwrap(), b"again");
        }
        let err = write_atomic(&dir.join("x".repeat(256)), b"png").unwrap_err().to_string();
        assert!(err.contains("256 bytes, more than the 255"), "{err}");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name()).collect();
        assert_eq!(left.len(), 4, "{left:?}");
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

    /// Streamed outputs appear only at the commit; dropped without one, nothing of them is left.
    #[test]
    fn staged_outputs_appear_all_at_the_commit_or_not_at_all() {
        let dir = temp_dir("staged");
        let (a, b) = (dir.join("a.mp4"), dir.join("b.png"));
        std::fs::write(&b, b"old").unwrap();
        let mut staged = Staged::default();
        staged.create(&a).unwrap().write_all(b"frames").unwrap();
        staged.create(&b).unwrap().write_all(b"new").unwrap();
        assert!(!a.exists() && std::fs::read(&b).unwrap() == b"old", "nothing placed before the commit");
        drop(staged);
        let names = |dir: &Path| std::fs::read_dir(dir).unwrap().count();
        assert_eq!((a.exists(), std::fs::read(&b).unwrap(), names(&dir)), (false, b"old".to_vec(), 1));
        let mut staged = Staged::default();
        staged.create(&a).unwrap().write_all(b"frames").unwrap();
        staged.create(&b).unwrap().write_all(b"new").unwrap();
        staged.commit().unwrap();
        assert_eq!((std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap()), (b"frames".to_vec(), b"new".to_vec()));
        assert_eq!(names(&dir), 2, "no temporary left");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
