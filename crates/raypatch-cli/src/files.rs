//! The files a run writes: where each PNG goes (--out, --segmentation, --depth), the raw outputs (--out-raw), all
//! checked before any GPU work and written all or none.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use safetensors::tensor::TensorView;
use safetensors::Dtype;

/// The files of a run, each with the flag that named it, and the folders to create for them.
pub struct OutputFiles {
    pub files: Vec<(&'static str, PathBuf)>,
    /// Folders named by a flag that do not exist yet: created when writing, removed again if the writes fail.
    new_folders: Vec<(&'static str, PathBuf)>,
}

/// Whether a PNG destination is a folder: an existing folder, or a name without extension that does not exist
/// (else a `.png` file). Anything else that exists there (a file without the extension, a device such as
/// /dev/null, a FIFO) is an error saying what it is.
pub fn is_folder(flag: &str, dest: &Path) -> Result<bool> {
    let expected = "expected a .png file, or a folder (a name without extension, or an existing folder)";
    let png = dest.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if png {
        return Ok(false);
    }
    match std::fs::metadata(dest) {
        Ok(meta) if meta.is_dir() => Ok(true),
        Ok(meta) if meta.is_file() => {
            bail!("{flag} {}: is an existing file without the .png extension; {expected}", dest.display())
        }
        Ok(meta) => {
            bail!("{flag} {}: is {}; {expected}", dest.display(), raypatch::raypatch_model::files::file_kind(&meta))
        }
        Err(_) if dest.extension().is_none() => Ok(true),
        Err(_) => bail!("{flag} {}: {expected}", dest.display()),
    }
}

/// The PNG path of each image a flag writes: `dest` itself for one image with a `.png` name, NAME_000.png,
/// ... for several, or `dest/<name>.png` when `dest` is a folder ([`is_folder`]). `names` are the images'
/// names in a folder.
pub fn png_paths(flag: &str, dest: &Path, names: &[String]) -> Result<Vec<PathBuf>> {
    let folder = is_folder(flag, dest)?;
    let stem = dest.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    Ok(names
        .iter()
        .enumerate()
        .map(|(i, name)| match (folder, names.len()) {
            (true, _) => dest.join(format!("{name}.png")),
            (false, 1) => dest.to_path_buf(),
            (false, _) => dest.with_file_name(format!("{stem}_{i:03}.png")),
        })
        .collect())
}

impl OutputFiles {
    /// Checks that every output can be written: its folder must exist (or be creatable, for one of the
    /// `folders` a flag names as its destination), anything already at its path must be a regular file, and no
    /// output may be another output or one of the `inputs` (flag, path).
    pub fn check(
        files: Vec<(&'static str, PathBuf)>,
        folders: &[(&'static str, &Path)],
        inputs: &[(&str, PathBuf)],
    ) -> Result<OutputFiles> {
        let mut new_folders: Vec<(&'static str, PathBuf)> = Vec::new();
        for &(flag, folder) in folders {
            if folder.exists() || new_folders.iter().any(|(_, f)| f == folder) {
                continue;
            }
            let parent = raypatch::folder_of(folder);
            if !parent.is_dir() {
                bail!("{flag} {}: cannot create the folder: {} is not a folder", folder.display(), parent.display());
            }
            new_folders.push((flag, folder.to_path_buf()));
        }
        let inputs: Vec<(&str, PathBuf)> = inputs.iter().map(|(flag, p)| (*flag, identity(p))).collect();
        let mut seen: Vec<(&str, PathBuf)> = Vec::new();
        for (flag, path) in &files {
            let id = identity(path);
            if let Some((other, _)) = seen.iter().find(|(_, p)| *p == id) {
                bail!("{flag} {}: the same file as an output of {other}", path.display());
            }
            if let Some((input, _)) = inputs.iter().find(|(_, p)| *p == id) {
                bail!("{flag} {}: would overwrite the input given by {input}", path.display());
            }
            if new_folders.iter().any(|(_, f)| path.parent() == Some(f.as_path())) {
                if std::fs::symlink_metadata(path).is_ok() {
                    bail!("{flag} {}: exists", path.display());
                }
            } else {
                raypatch::check_output_path(path).with_context(|| flag.to_string())?;
            }
            seen.push((flag, id));
        }
        Ok(OutputFiles { files, new_folders })
    }

    /// Writes `contents` (one per file, in order), creating the new folders first.
    pub fn write(&self, contents: &[Vec<u8>]) -> Result<()> {
        let mut created = Vec::new();
        let result = (|| {
            for (flag, folder) in &self.new_folders {
                std::fs::create_dir(folder)
                    .with_context(|| format!("{flag} {}: cannot create the folder", folder.display()))?;
                created.push(folder);
            }
            let files: Vec<(&Path, &[u8])> =
                self.files.iter().map(|(_, p)| p.as_path()).zip(contents.iter().map(Vec::as_slice)).collect();
            Ok(raypatch::write_all_atomic(&files)?)
        })();
        if result.is_err() {
            for folder in created.iter().rev() {
                let _ = std::fs::remove_dir(folder);
            }
        }
        result
    }

    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        self.files.iter().map(|(_, p)| p.as_path())
    }
}

/// Where a path points, for comparing outputs with each other and with the inputs: the canonical folder
/// joined with the file name (the file itself may not exist yet).
fn identity(path: &Path) -> PathBuf {
    let folder = raypatch::folder_of(path);
    let folder = folder.canonicalize().unwrap_or_else(|_| folder.to_path_buf());
    folder.join(path.file_name().unwrap_or_default())
}

/// A safetensors file with one tensor per output, named by the output: `[T,H,W,channels]`, or `[T,H,W]` for
/// one channel.
pub fn raw_bytes(rendered: &[raypatch::Rendered]) -> Result<Vec<u8>> {
    let region = rendered[0].region;
    let tensors: Vec<(String, Vec<u8>, Vec<usize>)> = rendered[0]
        .outputs
        .iter()
        .map(|first| {
            let values = rendered.iter().flat_map(|r| r.get(first.output).unwrap_or_default().iter().copied());
            let mut shape = vec![rendered.len(), region.height, region.width, first.channels];
            if first.channels == 1 {
                shape.pop();
            }
            (first.output.name().to_string(), values.flat_map(f32::to_le_bytes).collect(), shape)
        })
        .collect();
    let views = tensors
        .iter()
        .map(|(name, bytes, shape)| Ok((name.clone(), TensorView::new(Dtype::F32, shape.clone(), bytes)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
    let metadata = HashMap::from([("format".to_string(), "raypatch-frame/1".to_string())]);
    Ok(safetensors::serialize(views, Some(metadata))?)
}
