//! The pipeline cache on disk: compiled pipelines kept between runs, where the backend has a pipeline cache
//! (wgpu's `PIPELINE_CACHE`: Vulkan).
//!
//! A `Gpu` opens one file in the cache folder, named by the adapter (`wgpu::util::pipeline_cache_key`:
//! backend, vendor and device), creates its `wgpu::PipelineCache` from the file's data, compiles every
//! pipeline through it, and writes the cache's data back when the Gpu is dropped or on
//! `Gpu::save_pipeline_cache`, if pipelines were compiled since. Writes are atomic (a temporary file in the
//! same folder, renamed over the old one), so concurrent runs leave one whole file. Data wgpu rejects (another
//! driver version, another wgpu, garbage) starts the cache empty; no cache problem is fatal: IO errors are
//! printed to stderr once per process, but a folder that cannot be written (no home, a read-only one) only
//! means no cache, said by the status (`--timings`). [`prepare_driver_cache`] does the same for Mesa's own
//! shader cache.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

use raypatch_model::files::ReadError;

/// The environment variable naming the cache folder; the value `off` turns the cache off.
pub const CACHE_DIR_ENV: &str = "RAYPATCH_CACHE_DIR";

/// The first bytes of every `wgpu::PipelineCache::get_data` (wgpu-core's header magic).
const WGPU_MAGIC: &[u8; 8] = b"WGPUPLCH";
/// The largest cache file read: far above what the engine's few dozen pipelines take.
const MAX_CACHE_BYTES: u64 = 256 << 20;

/// Where the `Gpu` keeps compiled pipelines between runs (`GpuOptions::pipeline_cache`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum PipelineCacheDir {
    /// `$RAYPATCH_CACHE_DIR` (the value `off` turns the cache off), else `$XDG_CACHE_HOME/raypatch`, else
    /// `$HOME/.cache/raypatch` (empty variables count as unset); no cache when none is set.
    #[default]
    Auto,
    /// This folder (created when the cache is first written).
    Dir(PathBuf),
    /// No pipeline cache on disk.
    Off,
}

impl PipelineCacheDir {
    /// The cache folder, or why there is none.
    pub fn resolve(&self) -> Result<PathBuf, String> {
        self.resolve_with(|name| std::env::var_os(name))
    }

    /// [`resolve`](Self::resolve) with the environment given by `var`.
    pub fn resolve_with(&self, var: impl Fn(&str) -> Option<std::ffi::OsString>) -> Result<PathBuf, String> {
        match self {
            PipelineCacheDir::Off => Err("turned off".into()),
            PipelineCacheDir::Dir(dir) => Ok(dir.clone()),
            PipelineCacheDir::Auto => {
                let var = |name| var(name).filter(|v| !v.is_empty());
                if let Some(dir) = var(CACHE_DIR_ENV) {
                    if dir.eq_ignore_ascii_case("off") {
                        return Err(format!("{CACHE_DIR_ENV}=off"));
                    }
                    Ok(PathBuf::from(dir))
                } else if let Some(dir) = var("XDG_CACHE_HOME") {
                    Ok(PathBuf::from(dir).join("raypatch"))
                } else if let Some(home) = var("HOME") {
                    Ok(PathBuf::from(home).join(".cache").join("raypatch"))
                } else {
                    Err(format!("no cache folder ({CACHE_DIR_ENV}, XDG_CACHE_HOME and HOME are unset)"))
                }
            }
        }
    }
}

/// Why the folder `dir` cannot be written, if it cannot: the nearest of it and its parents that exists must be a
/// folder this process may write into (`access(2)`: ownership, mode and read-only mounts). Asked before a
/// cache is used, so that a home that does not exist or cannot be written costs no warning later.
pub fn unwritable(dir: &Path) -> Option<String> {
    let mut at = dir;
    loop {
        match std::fs::metadata(at) {
            Ok(meta) if meta.is_dir() => return access_error(at),
            Ok(_) => return Some(format!("{} is not a folder", at.display())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => match at.parent() {
                Some(parent) if !parent.as_os_str().is_empty() => at = parent,
                _ => return access_error(Path::new(".")),
            },
            Err(e) => return Some(format!("{}: {e}", at.display())),
        }
    }
}

#[cfg(unix)]
fn access_error(dir: &Path) -> Option<String> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: a NUL-terminated path that lives across the call, which only reads it.
    if unsafe { libc::access(path.as_ptr(), libc::W_OK | libc::X_OK) } == 0 {
        None
    } else {
        Some(format!("cannot write {}: {}", dir.display(), std::io::Error::last_os_error()))
    }
}

#[cfg(not(unix))]
fn access_error(_dir: &Path) -> Option<String> {
    None
}

/// Mesa's variables for its on-disk shader cache (the GLSL names are the older spellings): one set by the user
/// is left alone, and so are the others then.
pub const MESA_CACHE_VARS: [&str; 4] =
    ["MESA_SHADER_CACHE_DIR", "MESA_SHADER_CACHE_DISABLE", "MESA_GLSL_CACHE_DIR", "MESA_GLSL_CACHE_DISABLE"];

/// What Mesa's shader cache needs, with the environment given by `var`: Mesa writes it under
/// `$XDG_CACHE_HOME`, else `$HOME/.cache`, and says on stderr, once per driver it loads, where that fails (a
/// service account whose home does not exist, a read-only container). Where that folder cannot be written, the
/// variables that point Mesa's cache into raypatch's cache folder ([`PipelineCacheDir::Auto`], if that can be
/// written) or turn it off; and a note saying so (for `--timings`). Nothing where a Mesa variable is set, or
/// Mesa's folder can be written.
pub fn mesa_cache_env_with(
    var: impl Fn(&str) -> Option<std::ffi::OsString>,
    unwritable: impl Fn(&Path) -> Option<String>,
) -> (Vec<(&'static str, std::ffi::OsString)>, Option<String>) {
    if MESA_CACHE_VARS.iter().any(|name| var(name).is_some()) {
        return (Vec::new(), None);
    }
    let set = |name: &str| var(name).filter(|v| !v.is_empty());
    let mesa = match (set("XDG_CACHE_HOME"), set("HOME")) {
        (Some(dir), _) => Some(PathBuf::from(dir).join("mesa_shader_cache")),
        (None, Some(home)) => Some(PathBuf::from(home).join(".cache").join("mesa_shader_cache")),
        (None, None) => None,
    };
    let why = match &mesa {
        Some(dir) => match unwritable(dir) {
            None => return (Vec::new(), None),
            Some(why) => why,
        },
        None => "XDG_CACHE_HOME and HOME are unset".to_string(),
    };
    let ours = PipelineCacheDir::Auto.resolve_with(&var).map(|dir| dir.join("mesa_shader_cache"));
    match ours {
        Ok(dir) if unwritable(&dir).is_none() => {
            let note = format!("Mesa's shader cache: {} ({why})", dir.display());
            let value = std::ffi::OsString::from(dir);
            (vec![("MESA_SHADER_CACHE_DIR", value.clone()), ("MESA_GLSL_CACHE_DIR", value)], Some(note))
        }
        _ => (
            vec![("MESA_SHADER_CACHE_DISABLE", "true".into()), ("MESA_GLSL_CACHE_DISABLE", "true".into())],
            Some(format!("Mesa's shader cache: off ({why}, and raypatch's cache folder cannot hold it)")),
        ),
    }
}

/// [`mesa_cache_env_with`] of this process's environment.
pub fn mesa_cache_env() -> (Vec<(&'static str, std::ffi::OsString)>, Option<String>) {
    mesa_cache_env_with(|name| std::env::var_os(name), unwritable)
}

static DRIVER_CACHE_NOTE: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();

/// Sets Mesa's shader cache variables as [`mesa_cache_env`] says, once per process, and gives its note. They
/// must be set before the first wgpu instance is made (the driver reads them when it loads), and setting the
/// environment is sound only while no other thread reads or writes it (`std::env::set_var`): call this first
/// thing in `main`, before the program starts a thread (render-frame does, for its viewer too). Python's package
/// sets the same variables through `os.environ` when imported, under the GIL.
pub fn prepare_driver_cache() -> Option<&'static str> {
    DRIVER_CACHE_NOTE
        .get_or_init(|| {
            let (vars, note) = mesa_cache_env();
            for (name, value) in vars {
                std::env::set_var(name, value);
            }
            note
        })
        .as_deref()
}

/// The note of [`prepare_driver_cache`], if it moved or turned off Mesa's cache.
pub fn driver_cache_note() -> Option<&'static str> {
    DRIVER_CACHE_NOTE.get().and_then(|note| note.as_deref())
}

/// What a `Gpu` does with compiled pipelines (`Gpu::pipeline_cache_status`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PipelineCacheStatus {
    /// Pipelines go through the cache in `path`; `read_bytes` were read from it when the Gpu was created and
    /// given to wgpu (0: no file yet, not a wgpu pipeline cache, or one of another adapter). wgpu and the
    /// driver still ignore data of another driver or wgpu version.
    File { path: PathBuf, read_bytes: u64 },
    /// No pipeline cache on disk, and why (the backend has none, turned off, ...).
    Unavailable(String),
}

impl std::fmt::Display for PipelineCacheStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PipelineCacheStatus::File { path, read_bytes: 0 } => {
                write!(f, "pipeline cache {} (new)", path.display())
            }
            PipelineCacheStatus::File { path, read_bytes } => {
                write!(f, "pipeline cache {} ({:.1} KiB read)", path.display(), *read_bytes as f64 / 1024.0)
            }
            PipelineCacheStatus::Unavailable(why) => write!(f, "no pipeline cache: {why}"),
        }
    }
}

/// The file the adapter's cache would be in, or why there is none: asked before the device is created, as
/// the device needs `PIPELINE_CACHE` requested.
/// A folder that cannot be written (no home, a read-only one) means no cache, said by the status (`--timings`),
/// not by a warning on a run that may be failing for another reason.
pub(crate) fn cache_file(dir: &PipelineCacheDir, adapter: &wgpu::Adapter) -> Result<PathBuf, String> {
    let info = adapter.get_info();
    if !adapter.features().contains(wgpu::Features::PIPELINE_CACHE) {
        return Err(format!("the {:?} backend of {} has none", info.backend, info.name));
    }
    let Some(key) = wgpu::util::pipeline_cache_key(&info) else {
        return Err(format!("wgpu names no cache file for the {:?} backend", info.backend));
    };
    let dir = dir.resolve()?;
    if let Some(why) = unwritable(&dir) {
        return Err(why);
    }
    Ok(dir.join(key))
}

/// The features to request for the cache planned by [`cache_file`].
pub(crate) fn features(file: &Result<PathBuf, String>) -> wgpu::Features {
    match file {
        Ok(_) => wgpu::Features::PIPELINE_CACHE,
        Err(_) => wgpu::Features::empty(),
    }
}

/// A Gpu's pipeline cache and its file, or why there is none. Writes the cache back when dropped.
pub(crate) struct DiskCache {
    state: Result<Open, String>,
}

struct Open {
    cache: wgpu::PipelineCache,
    path: PathBuf,
    read_bytes: u64,
    /// Whether pipelines were compiled since the data was last read or written.
    dirty: AtomicBool,
    /// A hash of the data last read or written, so that unchanged data is not written again.
    saved: Mutex<u64>,
}

/// Whether a cache problem was printed already (once per process).
static WARNED: AtomicBool = AtomicBool::new(false);

fn warn(message: &str) {
    if !WARNED.swap(true, Ordering::Relaxed) {
        eprintln!("raypatch: pipeline cache: {message}");
    }
}

fn hash(data: &[u8]) -> u64 {
    let mut h = DefaultHasher::new();
    data.hash(&mut h);
    h.finish()
}

impl DiskCache {
    /// Opens the cache in `file` (from [`cache_file`]) on `device`, which was created with [`features`].
    pub(crate) fn open(device: &wgpu::Device, file: Result<PathBuf, String>) -> DiskCache {
        let path = match file {
            Ok(path) => path,
            Err(why) => return DiskCache { state: Err(why) },
        };
        // Read like every other input (a FIFO or device there must not hang or flood the run); a path that
        // is not a regular file, or is too large to be a cache, is left alone: neither read nor replaced.
        let data = match raypatch_model::files::read_regular(&path, MAX_CACHE_BYTES) {
            Ok(data) if data.starts_with(WGPU_MAGIC) => Some(data),
            Ok(_) => {
                warn(&format!("{} is not a wgpu pipeline cache: starting empty, to replace it", path.display()));
                None
            }
            Err(ReadError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e @ (ReadError::NotRegular(_) | ReadError::TooLarge { .. })) => {
                let why = format!("{} {e}: not used", path.display());
                warn(&why);
                return DiskCache { state: Err(why) };
            }
            Err(e) => {
                warn(&format!("cannot read {}: {e}; starting empty", path.display()));
                None
            }
        };
        let create = |data: Option<&[u8]>| {
            let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
            // SAFETY: the data is what `PipelineCache::get_data` returned on an earlier run, written whole
            // (atomic rename) into the file named for this adapter; wgpu checks its header (wgpu version,
            // adapter, driver, size) and the driver its own, and data that fails either starts the cache
            // empty (`fallback`, or the error caught below).
            let cache = unsafe {
                device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
                    label: Some("raypatch pipeline cache"),
                    data,
                    fallback: true,
                })
            };
            let error = pollster::block_on(scope.pop()).map(|e| match e {
                // Its last line is the cause, e.g. "The cache data was created for a different device".
                wgpu::Error::Validation { description, .. } => {
                    description.lines().map(str::trim).rfind(|l| !l.is_empty()).unwrap_or("").to_string()
                }
                e => e.to_string(),
            });
            (cache, error)
        };
        let (cache, read_bytes) = match create(data.as_deref()) {
            (cache, None) => (cache, data.as_ref().map_or(0, |d| d.len() as u64)),
            (_, Some(error)) => {
                // Data for another adapter, which wgpu refuses even with `fallback`.
                warn(&format!("{} is another adapter's ({error}): starting empty, to replace it", path.display()));
                match create(None) {
                    (cache, None) => (cache, 0),
                    (_, Some(error)) => {
                        return DiskCache { state: Err(format!("wgpu refused to create one: {error}")) }
                    }
                }
            }
        };
        let saved = Mutex::new(if read_bytes > 0 { data.as_deref().map_or(0, hash) } else { 0 });
        DiskCache { state: Ok(Open { cache, path, read_bytes, dirty: AtomicBool::new(false), saved }) }
    }

    /// The wgpu cache pipelines are compiled through, if any.
    pub(crate) fn wgpu(&self) -> Option<&wgpu::PipelineCache> {
        self.state.as_ref().ok().map(|open| &open.cache)
    }

    /// Notes that a pipeline was compiled (through [`wgpu`](Self::wgpu)).
    pub(crate) fn compiled(&self) {
        if let Ok(open) = &self.state {
            open.dirty.store(true, Ordering::Relaxed);
        }
    }

    pub(crate) fn status(&self) -> PipelineCacheStatus {
        match &self.state {
            Ok(open) => PipelineCacheStatus::File { path: open.path.clone(), read_bytes: open.read_bytes },
            Err(why) => PipelineCacheStatus::Unavailable(why.clone()),
        }
    }

    /// Writes the cache's data to its file if pipelines were compiled since the last write and the data
    /// changed. Whether it wrote.
    pub(crate) fn save(&self) -> std::io::Result<bool> {
        let Ok(open) = &self.state else {
            return Ok(false);
        };
        if !open.dirty.swap(false, Ordering::Relaxed) {
            return Ok(false);
        }
        let Some(data) = open.cache.get_data() else {
            return Ok(false);
        };
        let mut saved = open.saved.lock().unwrap_or_else(|e| e.into_inner());
        let h = hash(&data);
        if *saved == h {
            return Ok(false);
        }
        let result = write_atomic(&open.path, &data);
        match &result {
            Ok(()) => *saved = h,
            // Try again on the next save.
            Err(_) => open.dirty.store(true, Ordering::Relaxed),
        }
        result.map(|()| true)
    }
}

impl Drop for DiskCache {
    fn drop(&mut self) {
        if let (Err(e), Ok(open)) = (self.save(), &self.state) {
            warn(&format!("cannot write {}: {e}; pipelines are compiled anew next run", open.path.display()));
        }
    }
}

/// Writes `data` to a temporary file next to `path` (creating the folder), then renames it over `path`.
fn write_atomic(path: &Path, data: &[u8]) -> std::io::Result<()> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = path.parent().unwrap_or(Path::new("."));
    // The data is handed to the driver on the next run: keep the folder private to the user.
    let mut builder = std::fs::DirBuilder::new();
    builder.recursive(true);
    #[cfg(unix)]
    std::os::unix::fs::DirBuilderExt::mode(&mut builder, 0o700);
    builder.create(dir)?;
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("pipeline_cache");
    let temp = dir.join(format!(".{name}.{}.{}.tmp", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed)));
    let result = std::fs::write(&temp, data).and_then(|()| std::fs::rename(&temp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsString;

    fn resolve(dir: &PipelineCacheDir, vars: &[(&str, &str)]) -> Result<PathBuf, String> {
        dir.resolve_with(|name| vars.iter().find(|(n, _)| *n == name).map(|(_, v)| OsString::from(v)))
    }

    #[test]
    fn cache_folder_from_the_environment() {
        let auto = PipelineCacheDir::Auto;
        let all = [("RAYPATCH_CACHE_DIR", "/r"), ("XDG_CACHE_HOME", "/x"), ("HOME", "/h")];
        assert_eq!(resolve(&auto, &all), Ok(PathBuf::from("/r")));
        assert_eq!(resolve(&auto, &all[1..]), Ok(PathBuf::from("/x/raypatch")));
        assert_eq!(resolve(&auto, &all[2..]), Ok(PathBuf::from("/h/.cache/raypatch")));
        assert_eq!(
            resolve(&auto, &[("RAYPATCH_CACHE_DIR", ""), ("HOME", "/h")]),
            Ok(PathBuf::from("/h/.cache/raypatch"))
        );
        assert!(resolve(&auto, &[("RAYPATCH_CACHE_DIR", "off"), ("HOME", "/h")]).is_err());
        assert!(resolve(&auto, &[]).is_err());
        assert!(resolve(&PipelineCacheDir::Off, &all).is_err());
        assert_eq!(resolve(&PipelineCacheDir::Dir("/d".into()), &all), Ok(PathBuf::from("/d")));
    }

    #[test]
    fn mesa_cache_goes_where_it_can_be_written_or_off() {
        let env = |vars: &[(&str, &str)], bad: &[&str]| {
            let bad: Vec<PathBuf> = bad.iter().map(PathBuf::from).collect();
            let (set, note) = mesa_cache_env_with(
                |name| vars.iter().find(|(n, _)| *n == name).map(|(_, v)| OsString::from(v)),
                |dir| bad.iter().any(|b| dir.starts_with(b)).then(|| format!("cannot write {}", dir.display())),
            );
            let set: Vec<(String, String)> =
                set.into_iter().map(|(k, v)| (k.to_string(), v.to_string_lossy().into_owned())).collect();
            (set, note.unwrap_or_default())
        };
        // Mesa's own folder can be written: left alone; so is anything the user set.
        assert_eq!(env(&[("HOME", "/h")], &[]), (vec![], String::new()));
        assert_eq!(env(&[("HOME", "/h"), ("MESA_SHADER_CACHE_DIR", "/m")], &["/h", "/m"]), (vec![], String::new()));
        assert_eq!(env(&[("HOME", "/h"), ("MESA_GLSL_CACHE_DISABLE", "0")], &["/h"]), (vec![], String::new()));
        // HOME cannot be written, raypatch's folder can: Mesa's cache goes there.
        let (set, note) = env(&[("HOME", "/h"), ("RAYPATCH_CACHE_DIR", "/r")], &["/h"]);
        let dir = "/r/mesa_shader_cache".to_string();
        assert_eq!(set, [("MESA_SHADER_CACHE_DIR".into(), dir.clone()), ("MESA_GLSL_CACHE_DIR".into(), dir)]);
        assert!(note.contains("/r/mesa_shader_cache (cannot write /h/.cache/mesa_shader_cache)"), "{note}");
        // XDG_CACHE_HOME first, as Mesa reads it.
        assert_eq!(env(&[("HOME", "/h"), ("XDG_CACHE_HOME", "/x")], &["/h"]).0, vec![]);
        // Neither can be written, or raypatch's cache is off: Mesa's is off.
        for vars in [&[("HOME", "/h")][..], &[("HOME", "/h"), ("RAYPATCH_CACHE_DIR", "off")], &[]] {
            let (set, note) = env(vars, &["/h"]);
            assert_eq!(set.len(), 2, "{vars:?}");
            assert!(set.iter().all(|(k, v)| k.ends_with("_DISABLE") && v == "true"), "{set:?}");
            assert!(note.starts_with("Mesa's shader cache: off ("), "{note}");
        }
    }

    #[test]
    fn unwritable_folders_are_named() {
        let file = std::env::temp_dir().join(format!("raypatch-unwritable-{}", std::process::id()));
        std::fs::write(&file, b"x").unwrap();
        let why = unwritable(&file.join("home/.cache")).unwrap();
        std::fs::remove_file(&file).unwrap();
        assert!(why.contains("Not a directory") || why.contains("not a folder"), "{why}");
        assert_eq!(unwritable(&std::env::temp_dir().join("raypatch-none/a/b")), None);
    }
}
