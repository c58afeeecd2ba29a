//! A run's outputs checked before anything is written, for every surface (render-frame, the Python package's
//! Ray CLI): no two outputs are the same file, no output is an input or lies in an input folder, every folder
//! an output goes to exists or can be made, and every path can take a file. Files are compared by what they
//! are, not how they are named ([`same_file`]).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::staged::{check_output_path, folder_of, refused, Staged};
use crate::error::{Error, Result};

/// The outputs of a run, each with the flag that named it, and the folders to make for them.
pub struct OutputFiles {
    files: Vec<(String, PathBuf)>,
    /// Folders named by a flag that do not exist yet: made when writing begins, removed again if the writes
    /// fail.
    new_folders: Vec<(String, PathBuf)>,
}

impl OutputFiles {
    /// Checks that every output of `files` (flag, path) can be written: its folder exists, or is one of the
    /// `folders` (flag, folder) to make (whose parent exists or is made first), anything already at its path is
    /// a regular file, and no output is another output or one of the `inputs` (flag, path), or lies inside an
    /// input that is a folder (every file in it is an input: a frames folder).
    pub fn check(files: &[(&str, &Path)], folders: &[(&str, &Path)], inputs: &[(&str, &Path)]) -> Result<OutputFiles> {
        let mut new_folders: Vec<(String, PathBuf)> = Vec::new();
        for &(flag, folder) in folders {
            match (std::fs::metadata(folder), std::fs::symlink_metadata(folder)) {
                (Ok(meta), _) if meta.is_dir() => continue,
                // A file, or a symlink to nothing.
                (_, Ok(_)) => return Err(named(flag, refused(folder, "is not a folder"))),
                _ if new_folders.iter().any(|(_, f)| f == folder) => continue,
                _ => {}
            }
            let parent = folder_of(folder);
            if !parent.is_dir() && !new_folders.iter().any(|(_, f)| f == parent) {
                let why = if parent.exists() { "is not a folder" } else { "does not exist" };
                let reason = format!("cannot create the folder: {} {why}", parent.display());
                return Err(named(flag, refused(folder, reason)));
            }
            new_folders.push((flag.to_string(), folder.to_path_buf()));
        }
        let inputs = Inputs::of(inputs);
        let mut seen: HashMap<FileKey, &str> = HashMap::new();
        for &(flag, path) in files {
            let key = FileKey::of(path);
            if let Some(other) = seen.get(&key) {
                return Err(named(flag, refused(path, format!("the same file as an output of {other}"))));
            }
            inputs.refuse(flag, path, &key)?;
            if new_folders.iter().any(|(_, f)| f == folder_of(path)) {
                if std::fs::symlink_metadata(path).is_ok() {
                    return Err(named(flag, refused(path, "exists")));
                }
            } else {
                check_output_path(path).map_err(|e| named(flag, e))?;
            }
            seen.insert(key, flag);
        }
        let files = files.iter().map(|&(flag, path)| (flag.to_string(), path.to_path_buf())).collect();
        Ok(OutputFiles { files, new_folders })
    }

    /// Starts writing: makes the new folders; each output is then a temporary until [`Staged::commit`].
    pub fn begin(&self) -> Result<Staged> {
        let mut staged = Staged::default();
        for (flag, folder) in &self.new_folders {
            staged.create_folder(folder).map_err(|e| named(flag, e))?;
        }
        Ok(staged)
    }

    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        self.files.iter().map(|(_, p)| p.as_path())
    }
}

/// The inputs outputs are checked against: files by what they are, folders by where they are.
struct Inputs<'a> {
    files: HashMap<FileKey, &'a str>,
    folders: Vec<(&'a str, &'a Path, PathBuf)>,
}

impl<'a> Inputs<'a> {
    fn of(inputs: &[(&'a str, &'a Path)]) -> Inputs<'a> {
        let mut files = HashMap::new();
        let mut folders = Vec::new();
        for &(flag, path) in inputs {
            if path.is_dir() {
                folders.push((flag, path, resolved(path)));
            } else {
                files.entry(FileKey::of(path)).or_insert(flag);
            }
        }
        Inputs { files, folders }
    }

    /// Refuses `output` (its [`FileKey`] `key`) where it is an input or lies in an input folder.
    fn refuse(&self, flag: &str, output: &Path, key: &FileKey) -> Result<()> {
        if let Some(input) = self.files.get(key) {
            return Err(named(flag, refused(output, format!("would overwrite the input given by {input}"))));
        }
        let place = resolved(output);
        if let Some((input, folder, _)) = self.folders.iter().find(|(_, _, real)| place.starts_with(real)) {
            let reason = format!("would write into {}, given by {input}", folder.display());
            return Err(named(flag, refused(output, reason)));
        }
        Ok(())
    }
}

/// An error about an output, with the flag that named it in front of its path.
fn named(flag: &str, e: Error) -> Error {
    match e {
        Error::Output { path, reason } => Error::Output { path: format!("{flag} {path}"), reason },
        Error::Io { path, action, source } => Error::Io { path: format!("{flag} {path}"), action, source },
        other => other,
    }
}

/// Whether `a` and `b` are the same file, by any path: `./`, `..`, symlinks and hard links. A file that does
/// not exist yet can only be the same as another through its canonical folder and name.
pub fn same_file(a: &Path, b: &Path) -> bool {
    FileKey::of(a) == FileKey::of(b)
}

/// What a path names, for comparing files: the device and inode of an existing file; else its canonical folder
/// joined with the rest of the path.
#[derive(PartialEq, Eq, Hash)]
enum FileKey {
    #[cfg(unix)]
    Inode(u64, u64),
    Path(PathBuf),
}

impl FileKey {
    fn of(path: &Path) -> FileKey {
        #[cfg(unix)]
        if let Ok(meta) = std::fs::metadata(path) {
            use std::os::unix::fs::MetadataExt;
            return FileKey::Inode(meta.dev(), meta.ino());
        }
        FileKey::Path(resolved(path))
    }
}

/// `path` with its longest leading part that exists made canonical (absolute, links resolved) and the rest
/// joined as named.
fn resolved(path: &Path) -> PathBuf {
    let mut rest = Vec::new();
    let mut head = path;
    loop {
        if let Ok(real) = head.canonicalize() {
            return rest.iter().rev().fold(real, |p, name| p.join(name));
        }
        match head.file_name() {
            Some(name) => {
                rest.push(name);
                head = folder_of(head);
            }
            None => return path.to_path_buf(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same file by any path (symlinks, hard links, `..`), and files not there yet by folder and name.
    #[cfg(unix)]
    #[test]
    fn same_file_by_any_path() {
        let dir = std::env::temp_dir().join(format!("raypatch-same-file-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let file = dir.join("model.safetensors");
        std::fs::write(&file, b"m").unwrap();
        std::fs::hard_link(&file, dir.join("hard")).unwrap();
        std::os::unix::fs::symlink(&file, dir.join("soft")).unwrap();
        std::os::unix::fs::symlink(&dir, dir.join("sub/up")).unwrap();
        for other in ["hard", "soft", "sub/../model.safetensors", "sub/up/model.safetensors", "sub/up/hard"] {
            assert!(same_file(&file, &dir.join(other)), "{other}");
        }
        assert!(same_file(&dir.join("sub/new.png"), &dir.join("sub/up/sub/new.png")));
        assert!(!same_file(&dir.join("sub/new.png"), &dir.join("new.png")));
        assert!(!same_file(&file, &dir.join("sub/model.safetensors")));
        let inputs = [("--model", dir.join("soft")), ("--scene", dir.join("sub"))];
        let inputs: Vec<(&str, &Path)> = inputs.iter().map(|(f, p)| (*f, p.as_path())).collect();
        for (out, said) in [
            ("hard", "--out-raw DIR/hard: would overwrite the input given by --model"),
            ("sub/up/sub/x.png", "--out-raw DIR/sub/up/sub/x.png: would write into DIR/sub, given by --scene"),
        ] {
            let out = dir.join(out);
            let err = OutputFiles::check(&[("--out-raw", &out)], &[], &inputs).err().unwrap().to_string();
            assert_eq!(err.replace(&dir.display().to_string(), "DIR"), said);
        }
        let (a, b) = (dir.join("a.png"), dir.join("sub/up/a.png"));
        let err = OutputFiles::check(&[("--out", &a), ("--depth", &b)], &[], &[]).err().unwrap().to_string();
        assert!(err.ends_with("a.png: the same file as an output of --out"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// New folders, nested ones included, are made when writing begins and removed again without a commit.
    #[test]
    fn new_folders_are_checked_then_made_for_the_writes() {
        let dir = std::env::temp_dir().join(format!("raypatch-plan-folders-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (out, scene) = (dir.join("views"), dir.join("views/a"));
        let view = scene.join("view_000.png");
        let err = OutputFiles::check(&[("--out", &view)], &[("--out", &scene)], &[]).err().unwrap().to_string();
        assert!(err.contains("cannot create the folder: ") && err.ends_with("views does not exist"), "{err}");
        let files = OutputFiles::check(&[("--out", &view)], &[("--out", &out), ("--out", &scene)], &[]).unwrap();
        let mut staged = files.begin().unwrap();
        staged.write(&view, b"png").unwrap();
        drop(staged);
        assert!(!out.exists());
        let mut staged = files.begin().unwrap();
        staged.write(&view, b"png").unwrap();
        staged.commit().unwrap();
        assert_eq!(std::fs::read(&view).unwrap(), b"png");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
