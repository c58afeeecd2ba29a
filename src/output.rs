//! Output files, written so that nothing is lost: every output is checked before any is written, all are
//! written to temporaries in their own folders, and only when every write succeeded are they moved into
//! place, all or none: an existing file is first moved aside, and when any move fails every move done is
//! undone. A path that exists must be a regular file: a symlink, FIFO, device or folder there is refused,
//! never replaced. Temporaries are unique per process and listed in one registry of the process
//! ([`PENDING`]), which [`clean_up_on_signals`] empties when the process is interrupted; ones left by a killed
//! run (SIGKILL, a power cut) are removed later, and files it had moved aside are put back.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

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
/// [`write_all_atomic`] does; dropped without a commit (an error, a panic), the temporaries and the folders
/// made for them are removed. While they exist they are in the process's registry ([`PENDING`]), so that an
/// interrupted run removes them too ([`clean_up_on_signals`]).
#[derive(Default)]
pub struct Staged {
    /// (temporary, destination), in the order they were created.
    files: Vec<(PathBuf, PathBuf)>,
    /// Folders made for the outputs, in the order they were made.
    folders: Vec<PathBuf>,
}

/// What the process has on disk that is not yet an output: temporaries and the new folders made for
/// outputs. Whoever holds the lock may change the disk: [`Staged`] creates, removes and commits its files under
/// it, so a signal's clean-up ([`clean_up_on_signals`]) never runs half-way through a commit and nothing is
/// created after it.
struct Pending {
    temporaries: Vec<PathBuf>,
    folders: Vec<PathBuf>,
}

static PENDING: Mutex<Pending> = Mutex::new(Pending { temporaries: Vec::new(), folders: Vec::new() });

fn pending() -> MutexGuard<'static, Pending> {
    // A panic while the lock was held leaves the lists as they were: still right to use.
    PENDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Pending {
    fn forget(&mut self, tmp: &Path) {
        self.temporaries.retain(|t| t != tmp);
    }

    /// Removes every temporary, then every folder made for outputs (the newest first; only if empty).
    fn remove_all(&mut self) {
        for tmp in self.temporaries.drain(..) {
            let _ = std::fs::remove_file(tmp);
        }
        for folder in self.folders.drain(..).rev() {
            let _ = std::fs::remove_dir(folder);
        }
    }
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
        let mut pending = pending();
        // create_new: never follows or reuses anything already at the temporary's name.
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp);
        let file = file.map_err(|e| Error::io(path, "cannot write", e))?;
        pending.temporaries.push(tmp.clone());
        self.files.push((tmp, path.to_path_buf()));
        Ok(file)
    }

    /// Makes a new folder for outputs (its parent must exist); it is removed again, when empty, if the outputs
    /// are not committed.
    pub fn create_folder(&mut self, folder: &Path) -> Result<()> {
        let mut pending = pending();
        std::fs::create_dir(folder).map_err(|e| Error::io(folder, "cannot create the folder", e))?;
        pending.folders.push(folder.to_path_buf());
        self.folders.push(folder.to_path_buf());
        Ok(())
    }

    /// Flushes every temporary to disk and moves them all into place, all or none.
    pub fn commit(mut self) -> Result<()> {
        let files = std::mem::take(&mut self.files);
        let synced = files.iter().try_for_each(|(tmp, dest)| {
            std::fs::File::open(tmp).and_then(|f| f.sync_all()).map_err(|e| Error::io(dest, "cannot write", e))
        });
        let moves: Vec<(&Path, &Path)> = files.iter().map(|(t, d)| (t.as_path(), d.as_path())).collect();
        let mut pending = pending();
        let placed = synced.and_then(|()| move_all_into_place(&moves));
        match placed {
            Ok(()) => {
                for (tmp, _) in &files {
                    pending.forget(tmp);
                }
                let folders = std::mem::take(&mut self.folders);
                pending.folders.retain(|f| !folders.contains(f));
            }
            Err(_) => self.files = files,
        }
        placed
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        let mut pending = pending();
        for (tmp, _) in &self.files {
            let _ = std::fs::remove_file(tmp);
            pending.forget(tmp);
        }
        for folder in self.folders.iter().rev() {
            let _ = std::fs::remove_dir(folder);
            pending.folders.retain(|f| f != folder);
        }
    }
}

/// From now on, SIGINT and SIGTERM (and SIGHUP: a closed terminal) end the process at once with 128 + the
/// signal's number (130, 143, 129), as a shell reports a process the signal killed, after removing every
/// temporary and new folder of [`Staged`] outputs not yet committed: a stopped run leaves nothing behind and
/// never a half-written output. A commit under way is finished first (its renames are all or none), and
/// nothing is created afterwards. For programs like `render-frame`; a library's caller keeps its own handling.
#[cfg(unix)]
pub fn clean_up_on_signals() -> Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])
        .map_err(|e| Error::io(Path::new("signals"), "cannot handle", e))?;
    std::thread::Builder::new()
        .name("raypatch-signals".into())
        .spawn(move || {
            if let Some(signal) = signals.forever().next() {
                // Held until the process ends: nothing is created or moved into place after the clean-up.
                let mut pending = pending();
                pending.remove_all();
                // _exit: no atexit handlers, which could wait on the GPU driver the other threads are in.
                unsafe { libc::_exit(128 + signal) }
            }
        })
        .map_err(|e| Error::io(Path::new("signals"), "cannot handle", e))?;
    Ok(())
}

/// Elsewhere the platform's default (the process ends); temporaries are removed by a later run.
#[cfg(not(unix))]
pub fn clean_up_on_signals() -> Result<()> {
    Ok(())
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

/// The process id in the name of one of our temporaries (`.tmp`) or files moved aside (`.bak`), and which.
fn temporary_owner(name: &str) -> Option<(u32, &'static str)> {
    let (rest, ext) = match name.strip_suffix(".tmp") {
        Some(rest) => (rest, "tmp"),
        None => (name.strip_suffix(".bak")?, "bak"),
    };
    let (_, tail) = rest.rsplit_once(TEMP_MARK)?;
    let (pid, n) = tail.split_once('-')?;
    n.parse::<u64>().ok()?;
    Some((pid.parse().ok()?, ext))
}

/// The output a file moved aside by [`sibling`] belongs to, `.NAME.raypatch-PID-N.bak` → `NAME`; `None` where
/// NAME may have been shortened to fit (the name is at the length limit).
fn moved_aside_from(bak: &Path) -> Option<PathBuf> {
    let name = bak.file_name()?.to_str()?;
    // sibling() shortens NAME only to keep the whole within MAX_NAME_BYTES; a char boundary may cost 3 bytes.
    if name.len() + 3 >= MAX_NAME_BYTES {
        return None;
    }
    let (dotted, _) = name.rsplit_once(TEMP_MARK)?;
    let original = dotted.strip_prefix('.').filter(|n| !n.is_empty())?;
    Some(bak.with_file_name(original))
}

/// Cleans up after runs of ours in `folder` whose process is gone (killed without a chance to clean up):
/// removes their temporaries, and puts each file they had moved aside back in place where nothing took its
/// place (a commit interrupted between its two renames), else removes it (the commit had placed the new
/// file). Where process ids cannot be checked (no /proc), files older than a day count as stale.
fn remove_stale_temporaries(folder: &Path) {
    let Ok(entries) = std::fs::read_dir(folder) else { return };
    let proc = Path::new("/proc/self").exists();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some((pid, ext)) = temporary_owner(&name) else { continue };
        let Ok(meta) = std::fs::symlink_metadata(entry.path()) else { continue };
        let stale = if proc {
            pid != std::process::id() && !Path::new("/proc").join(pid.to_string()).exists()
        } else {
            meta.modified().ok().and_then(|t| t.elapsed().ok()).is_some_and(|age| age.as_secs() > 24 * 3600)
        };
        if !stale || !meta.is_file() {
            continue;
        }
        if ext == "tmp" {
            let _ = std::fs::remove_file(entry.path());
        } else if let Some(original) = moved_aside_from(&entry.path()) {
            if file_exists(&original) {
                let _ = std::fs::remove_file(entry.path());
            } else {
                let _ = std::fs::rename(entry.path(), original);
            }
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

    /// A run killed between a commit's two renames left the user's file moved aside: the next run in the
    /// folder puts it back, or removes it where the new file was already placed.
    #[test]
    fn files_moved_aside_by_dead_runs_are_put_back() {
        let dir = temp_dir("aside");
        let aside = |name: &str| dir.join(format!(".{name}{TEMP_MARK}4294967294-3.bak"));
        std::fs::write(aside("lost.png"), b"user's").unwrap();
        std::fs::write(aside("placed.png"), b"old").unwrap();
        std::fs::write(dir.join("placed.png"), b"new").unwrap();
        write_atomic(&dir.join("other.png"), b"png").unwrap();
        if Path::new("/proc/self").exists() {
            assert_eq!(std::fs::read(dir.join("lost.png")).unwrap(), b"user's");
            assert_eq!(std::fs::read(dir.join("placed.png")).unwrap(), b"new");
            assert!(!aside("lost.png").exists() && !aside("placed.png").exists());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// What a signal's clean-up removes: every temporary and new folder of outputs not yet committed, and
    /// nothing of a commit that is done.
    #[test]
    fn the_registry_holds_exactly_what_is_not_yet_committed() {
        let dir = temp_dir("registry");
        let registered = |path: &Path| pending().temporaries.iter().any(|t| t.starts_with(path));
        let folder = dir.join("new");
        let mut staged = Staged::default();
        staged.create_folder(&folder).unwrap();
        staged.create(&folder.join("a.png")).unwrap().write_all(b"a").unwrap();
        assert!(registered(&folder) && pending().folders.contains(&folder));
        staged.commit().unwrap();
        assert!(!registered(&folder) && !pending().folders.contains(&folder));
        assert_eq!(std::fs::read(folder.join("a.png")).unwrap(), b"a");
        let mut staged = Staged::default();
        let other = dir.join("other");
        staged.create_folder(&other).unwrap();
        staged.create(&other.join("b.png")).unwrap();
        drop(staged);
        assert!(!registered(&other) && !other.exists());
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
