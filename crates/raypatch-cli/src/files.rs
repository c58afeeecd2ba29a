//! The files a run writes: where each PNG goes (--out, --segmentation, --depth), the raw outputs (--out-raw), all
//! checked before any GPU work (raypatch's OutputFiles) and written all or none.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use raypatch::{Output, OutputFiles, Outputs, SceneData};
use safetensors::tensor::TensorView;
use safetensors::Dtype;

use crate::cameras::Shot;
use crate::video::{check_video_size, VideoFormat};
use crate::Args;

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

/// Where --out's images go: one video file, or one PNG per image.
pub enum OutDest {
    Video(PathBuf, VideoFormat),
    Pngs(Vec<PathBuf>),
}

/// Every file a run writes, per image where there is one per image, all checked before any GPU work.
pub struct Destinations {
    /// --out, unless rgb is not rendered.
    pub out: Option<OutDest>,
    /// --segmentation's and --depth's PNGs, one per image (empty without the flag).
    pub segmentation: Vec<PathBuf>,
    pub depth: Vec<PathBuf>,
    pub raw: Option<PathBuf>,
    pub files: OutputFiles,
}

impl Destinations {
    /// --out's path, for messages.
    pub fn out_path(&self) -> &Path {
        match &self.out {
            Some(OutDest::Video(path, _)) => path,
            Some(OutDest::Pngs(paths)) => paths.first().map_or(Path::new(""), PathBuf::as_path),
            None => Path::new(""),
        }
    }
}

/// The files the run writes (--out's video or PNGs, segmentation PNGs, depth PNGs, the raw outputs), checked
/// before any GPU work.
pub fn destinations<'a>(args: &'a Args, shots: &[Shot], data: &SceneData, outputs: Outputs) -> Result<Destinations> {
    let names: Vec<String> = shots.iter().map(|s| s.name.clone()).collect();
    let mut files: Vec<(&'static str, PathBuf)> = Vec::new();
    let mut folders: Vec<(&'static str, &Path)> = Vec::new();
    let video = VideoFormat::of(&args.out)?;
    if args.fps.is_some() && video.is_none() {
        bail!("--fps: only for a video, --out NAME.mp4 or NAME.gif (--out {} is not one)", args.out.display());
    }
    if args.mp4.is_some() && video != Some(VideoFormat::Mp4) {
        bail!("--mp4: only for --out NAME.mp4 (--out {} is not one)", args.out.display());
    }
    let png = args.out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if video.is_none() && !png && args.out.extension().is_some() && !args.out.is_dir() {
        bail!(
            "--out {}: expected a .png file, a video (.mp4 or .gif), or a folder (a name without extension, or an \
             existing folder)",
            args.out.display()
        );
    }
    if args.panels.is_some() && !outputs.contains(Output::Rgb) {
        bail!("--panels: the panels are --out's images; add rgb to --outputs");
    }
    let rgb = outputs.contains(Output::Rgb);
    let out = match video {
        Some(format) => {
            if !rgb {
                bail!("--out {}: a video shows the rgb output; add rgb to --outputs", args.out.display());
            }
            let sizes: Vec<(usize, usize)> = shots.iter().map(|s| frame_size(args, &s.camera)).collect();
            if let Some(other) = sizes.iter().find(|&&s| s != sizes[0]) {
                bail!(
                    "--out {}: a video's frames have one size, these are {:?} and {:?}",
                    args.out.display(),
                    sizes[0],
                    other
                );
            }
            let (width, height) = sizes[0];
            // Panels are laid out at even sizes.
            if args.panels.is_none() {
                check_video_size(&args.out, format, args.mp4.unwrap_or_default(), width, height)?;
            }
            files.push(("--out", args.out.clone()));
            Some(OutDest::Video(args.out.clone(), format))
        }
        None if rgb => {
            let paths = png_paths("--out", &args.out, &names)?;
            files.extend(paths.iter().map(|p| ("--out", p.clone())));
            if is_folder("--out", &args.out)? {
                folders.push(("--out", &args.out));
            }
            Some(OutDest::Pngs(paths))
        }
        None => None,
    };
    let mut per_image = |flag: &'static str, dest: Option<&'a PathBuf>| -> Result<Vec<PathBuf>> {
        let Some(dest) = dest else { return Ok(Vec::new()) };
        let paths = png_paths(flag, dest, &names)?;
        files.extend(paths.iter().map(|p| (flag, p.clone())));
        if is_folder(flag, dest)? {
            folders.push((flag, dest));
        }
        Ok(paths)
    };
    let segmentation = per_image("--segmentation", args.segmentation.as_ref())?;
    let depth = per_image("--depth", args.depth.as_ref())?;
    if let Some(path) = &args.out_raw {
        if path.extension().is_none_or(|e| !e.eq_ignore_ascii_case("safetensors")) {
            bail!("--out-raw {}: expected a file name ending in .safetensors", path.display());
        }
        files.push(("--out-raw", path.clone()));
    }
    let mut inputs: Vec<(&str, &Path)> = data.files.iter().map(|f| ("--scene", f.as_path())).collect();
    let cameras = &args.cameras;
    for (flag, path) in [("--model", &args.model), ("--pose", &cameras.pose), ("--camera-path", &cameras.camera_path)] {
        if let Some(path) = path {
            inputs.push((flag, path));
        }
    }
    let outputs: Vec<(&str, &Path)> = files.iter().map(|(flag, p)| (*flag, p.as_path())).collect();
    let files = OutputFiles::check(&outputs, &folders, &inputs)?;
    Ok(Destinations { out, segmentation, depth, raw: args.out_raw.clone(), files })
}

/// The size of --out's image of a camera: the region's, or the camera's.
fn frame_size(args: &Args, camera: &raypatch::Camera) -> (usize, usize) {
    args.region.map_or((camera.width(), camera.height()), |r| (r.width, r.height))
}
