//! Writing outputs all or none: each is a temporary in its own folder until [`Staged::commit`] moves them all
//! into place, flushed to disk first; an existing file is first moved aside, and when any move fails every
//! move done is undone. Temporaries are named `.NAME.raypatch-PID-N.tmp` and listed in the process's registry
//! (`signals.rs`); ones a killed run left are removed by the next run writing beside them, and the files it
//! had moved aside (`.NAME.raypatch-PID-N.bak`) put back.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use raypatch_model::files::file_kind;

use super::signals::{pending, remove_temporary};
use crate::error::{Error, Result};

/// Marks our temporaries, `.NAME.raypatch-PID-N.tmp`, and the files moved aside while outputs are moved into
/// place, `.NAME.raypatch-PID-N.bak`.
pub const TEMP_MARK: &str = ".raypatch-";

/// The longest file name most file systems take (bytes).
pub const MAX_NAME_BYTES: usize = 255;

/// An output refused for `reason`.
pub(super) fn refused(path: &Path, reason: impl Into<String>) -> Error {
    Error::Output { path: path.display().to_string(), reason: reason.into() }
}

/// Checks that `path` can take an output: its folder exists, and if something is at `path` it is a regular
/// file (not followed if it is a symlink).
pub fn check_output_path(path: &Path) -> Result<()> {
    let Some(name) = path.file_name() else {
        return Err(refused(path, "expected a file name"));
    };
    if name.len() > MAX_NAME_BYTES {
        return Err(refused(
            path,
            format!("the name is {} bytes, more than the {MAX_NAME_BYTES} a file name may have", name.len()),
        ));
    }
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        if !meta.is_file() {
            return Err(refused(path, format!("is {}; only regular files are replaced", file_kind(&meta))));
        }
    }
    let folder = folder_of(path);
    if !folder.is_dir() {
        return Err(refused(path, format!("folder {} does not exist", folder.display())));
    }
    Ok(())
}

/// Writes `bytes` to `path` through a unique temporary file in the same folder and a rename, so that no
/// partial file is left behind. See [`write_all_atomic`].
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_all_atomic(&[(path, bytes)])
}

/// Writes every file or none: checks all paths ([`check_output_path`]), writes each to a temporary, and
/// moves them into place only when all were written. On an error the temporaries are removed and every
/// existing file is as it was.
pub fn write_all_atomic(files: &[(&Path, &[u8])]) -> Result<()> {
    for (path, _) in files {
        check_output_path(path)?;
    }
    let mut staged = Staged::default();
    for (path, bytes) in files {
        staged.write(path, bytes)?;
    }
    staged.commit()
}

/// Outputs being written, all or none, as they are made (a video's frames stream into its file): each is a
/// temporary in its own folder until [`commit`](Self::commit) moves them all into place as
/// [`write_all_atomic`] does; dropped without a commit (an error, a panic), the temporaries and the folders
/// made for them are removed. While they exist they are in the process's registry, so that an interrupted run
/// removes them too ([`clean_up_on_signals`](super::clean_up_on_signals)).
#[derive(Default)]
pub struct Staged {
    /// (temporary, destination), in the order they were created: files, and folders whose files become the
    /// destination folder's ([`stage_folder`](Self::stage_folder)).
    files: Vec<(PathBuf, PathBuf)>,
    /// Folders made for the outputs, in the order they were made.
    folders: Vec<PathBuf>,
    /// Folders whose temporaries left by killed runs were cleaned up.
    cleaned: Vec<PathBuf>,
}

impl Staged {
    /// Creates the temporary that will become `path` ([`check_output_path`] first) and opens it for writing.
    pub fn create(&mut self, path: &Path) -> Result<std::fs::File> {
        Ok(self.create_temporary(path)?.1)
    }

    /// Writes `bytes` as the output `path`.
    pub fn write(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        self.create(path)?.write_all(bytes).map_err(|e| Error::io(path, "cannot write", e))
    }

    /// Creates the temporary that will become `path`, empty, and gives its name: for a writer that opens it
    /// itself (Python's).
    pub fn temporary(&mut self, path: &Path) -> Result<PathBuf> {
        Ok(self.create_temporary(path)?.0)
    }

    fn create_temporary(&mut self, path: &Path) -> Result<(PathBuf, std::fs::File)> {
        check_output_path(path)?;
        let tmp = self.temporary_beside(path);
        let mut pending = pending();
        // create_new: never follows or reuses anything already at the temporary's name.
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp);
        let file = file.map_err(|e| Error::io(path, "cannot write", e))?;
        pending.add_temporary(tmp.clone());
        self.files.push((tmp.clone(), path.to_path_buf()));
        Ok((tmp, file))
    }

    /// Creates a temporary folder whose files (in subfolders too) become `folder`'s at the commit: `folder` is
    /// made then where missing, and files already in it stay unless an output replaces them. Other processes
    /// may write into it (Ray workers, each a scene).
    pub fn stage_folder(&mut self, folder: &Path) -> Result<PathBuf> {
        if let Ok(meta) = std::fs::metadata(folder) {
            if !meta.is_dir() {
                return Err(refused(folder, "is not a folder"));
            }
        } else if !folder_of(folder).is_dir() {
            return Err(refused(folder, format!("folder {} does not exist", folder_of(folder).display())));
        }
        let tmp = self.temporary_beside(folder);
        let mut pending = pending();
        std::fs::create_dir(&tmp).map_err(|e| Error::io(folder, "cannot write", e))?;
        pending.add_temporary(tmp.clone());
        self.files.push((tmp.clone(), folder.to_path_buf()));
        Ok(tmp)
    }

    /// A unique temporary's name beside `path`, after cleaning up, once per folder, after killed runs there.
    fn temporary_beside(&mut self, path: &Path) -> PathBuf {
        let folder = folder_of(path);
        if !self.cleaned.iter().any(|f| f == folder) {
            remove_stale_temporaries(folder);
            self.cleaned.push(folder.to_path_buf());
        }
        sibling(path, "tmp")
    }

    /// Makes a new folder for outputs (its parent must exist); it is removed again, when empty, if the outputs
    /// are not committed.
    pub fn create_folder(&mut self, folder: &Path) -> Result<()> {
        let mut pending = pending();
        std::fs::create_dir(folder).map_err(|e| Error::io(folder, "cannot create the folder", e))?;
        pending.add_folder(folder.to_path_buf());
        self.folders.push(folder.to_path_buf());
        Ok(())
    }

    /// Flushes every output to disk and moves them all into place, all or none.
    pub fn commit(mut self) -> Result<()> {
        let staged = std::mem::take(&mut self.files);
        let moves = Moves::of(&staged);
        let synced = moves.and_then(|moves| {
            for (tmp, dest) in &moves.files {
                std::fs::File::open(tmp).and_then(|f| f.sync_all()).map_err(|e| Error::io(dest, "cannot write", e))?;
            }
            Ok(moves)
        });
        let mut pending = pending();
        let placed = synced.and_then(|moves| move_all_into_place(&moves));
        match placed {
            Ok(()) => {
                for (tmp, _) in &staged {
                    // What is left of a staged folder: its emptied subfolders.
                    remove_temporary(tmp);
                    pending.forget(tmp);
                }
                for folder in std::mem::take(&mut self.folders) {
                    pending.forget_folder(&folder);
                }
            }
            Err(_) => self.files = staged,
        }
        placed
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        let mut pending = pending();
        for (tmp, _) in self.files.iter().rev() {
            remove_temporary(tmp);
            pending.forget(tmp);
        }
        for folder in self.folders.iter().rev() {
            let _ = std::fs::remove_dir(folder);
            pending.forget_folder(folder);
        }
    }
}

/// What a commit does: make the folders, then rename each temporary file to its destination.
struct Moves {
    folders: Vec<PathBuf>,
    files: Vec<(PathBuf, PathBuf)>,
}

impl Moves {
    /// The moves of staged outputs: a staged folder's files go to the same places under its destination, whose
    /// missing folders are made.
    fn of(staged: &[(PathBuf, PathBuf)]) -> Result<Moves> {
        let mut moves = Moves { folders: Vec::new(), files: Vec::new() };
        for (tmp, dest) in staged {
            match std::fs::symlink_metadata(tmp) {
                Ok(meta) if meta.is_dir() => moves.merge(tmp, dest)?,
                _ => moves.files.push((tmp.clone(), dest.clone())),
            }
        }
        Ok(moves)
    }

    fn merge(&mut self, tmp: &Path, dest: &Path) -> Result<()> {
        if !dest.is_dir() {
            self.folders.push(dest.to_path_buf());
        }
        let entries = std::fs::read_dir(tmp).map_err(|e| Error::io(dest, "cannot write", e))?;
        let mut entries: Vec<_> = entries.flatten().map(|e| (e.file_name(), e.path())).collect();
        entries.sort();
        for (name, path) in entries {
            if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir()) {
                self.merge(&path, &dest.join(name))?;
            } else {
                self.files.push((path, dest.join(name)));
            }
        }
        Ok(())
    }
}

/// One step of [`move_all_into_place`], to undo if a later one fails.
enum Moved<'a> {
    /// A folder was made for outputs.
    Made { folder: &'a Path },
    /// An existing file was moved aside to `backup`.
    Aside { dest: &'a Path, backup: PathBuf },
    /// A temporary was renamed to `dest`.
    Placed { dest: &'a Path },
}

/// Makes the folders and renames each `(temporary, destination)`, all or none. A destination that exists is
/// first moved aside (a rename within its folder), so that when a later step fails (a sticky folder where
/// another user owns the file, a destination swapped for a folder) every output placed and folder made is
/// removed and every file moved aside is put back.
fn move_all_into_place(moves: &Moves) -> Result<()> {
    let mut done: Vec<Moved> = Vec::with_capacity(moves.folders.len() + 2 * moves.files.len());
    let mut result = Ok(());
    for folder in &moves.folders {
        if !folder.is_dir() {
            if let Err(e) = std::fs::create_dir(folder) {
                result = Err(Error::io(folder, "cannot create the folder", e));
                break;
            }
            done.push(Moved::Made { folder });
        }
    }
    let files = if result.is_ok() { &moves.files[..] } else { &[] };
    for (tmp, dest) in files {
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
            (Moved::Made { folder }, Err(_)) => {
                let _ = std::fs::remove_dir(folder);
            }
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
            (Moved::Placed { .. } | Moved::Made { .. }, Ok(())) => {}
        }
    }
    match result {
        Err(e) if !kept_aside.is_empty() => Err(Error::Output { path: e.to_string(), reason: kept_aside.join(", ") }),
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

/// A unique name in `path`'s folder, `.NAME.raypatch-PID-N.EXT`, with NAME shortened so that the whole stays
/// within [`MAX_NAME_BYTES`] (any name an output may have gets a temporary).
pub fn sibling(path: &Path, ext: &str) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tail = format!("{TEMP_MARK}{}-{n}.{ext}", std::process::id());
    let mut keep = name.len().min(MAX_NAME_BYTES.saturating_sub(1 + tail.len()));
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
/// removes their temporaries (files and staged folders), and puts each file they had moved aside back in place
/// where nothing took its place (a commit interrupted between its two renames), else removes it (the commit
/// had placed the new file). Where process ids cannot be checked (no /proc), files older than a day count as
/// stale.
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
        if !stale || meta.is_symlink() {
            continue;
        }
        if ext == "tmp" {
            remove_temporary(&entry.path());
        } else if let Some(original) = moved_aside_from(&entry.path()).filter(|_| meta.is_file()) {
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
            let files =
                vec![(t1.clone(), keep.clone()), (t2.clone(), fresh.clone()), (last_tmp.clone(), last_dest.into())];
            let err = move_all_into_place(&Moves { folders: Vec::new(), files }).unwrap_err().to_string();
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
        let registered = |path: &Path| pending().holds(path);
        let folder = dir.join("new");
        let mut staged = Staged::default();
        staged.create_folder(&folder).unwrap();
        staged.create(&folder.join("a.png")).unwrap().write_all(b"a").unwrap();
        assert!(registered(&folder));
        staged.commit().unwrap();
        assert!(!registered(&folder));
        assert_eq!(std::fs::read(folder.join("a.png")).unwrap(), b"a");
        let mut staged = Staged::default();
        let other = dir.join("other");
        staged.create_folder(&other).unwrap();
        staged.create(&other.join("b.png")).unwrap();
        drop(staged);
        assert!(!registered(&other) && !other.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A staged folder's files join the destination folder's at the commit (made where missing, files already
    /// there kept); dropped, nothing of it is left; a killed run's staged folder is removed.
    #[test]
    fn staged_folders_merge_at_the_commit() {
        let dir = temp_dir("folders");
        let views = dir.join("views");
        std::fs::create_dir_all(views.join("a")).unwrap();
        std::fs::write(views.join("a/mine.txt"), b"mine").unwrap();
        std::fs::write(views.join("a/view_000.png"), b"old").unwrap();
        let stale = dir.join(format!(".views{TEMP_MARK}4294967294-0.tmp"));
        std::fs::create_dir_all(stale.join("a")).unwrap();
        let ours = |dir: &Path| std::fs::read_dir(dir).unwrap().flatten().filter(|e| e.path() != views).count();
        for commit in [false, true] {
            let mut staged = Staged::default();
            let tmp = staged.stage_folder(&views).unwrap();
            for scene in ["a", "b"] {
                std::fs::create_dir_all(tmp.join(scene)).unwrap();
                std::fs::write(tmp.join(scene).join("view_000.png"), b"new").unwrap();
            }
            match commit {
                true => staged.commit().unwrap(),
                false => drop(staged),
            }
            let want: &[u8] = if commit { b"new" } else { b"old" };
            assert_eq!(std::fs::read(views.join("a/view_000.png")).unwrap(), want);
            assert_eq!(views.join("b/view_000.png").exists(), commit);
            assert_eq!(std::fs::read(views.join("a/mine.txt")).unwrap(), b"mine");
            if Path::new("/proc/self").exists() {
                assert_eq!(ours(&dir), 0, "no temporary left");
            }
        }
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
