//! The pipeline cache on disk (`raypatch_engine::pipeline_cache`): written after pipelines were compiled,
//! read by the next Gpu on the same folder, and never fatal: garbage files and files of another adapter start
//! the cache empty. On an adapter without a pipeline cache (not Vulkan), the tests check the reason instead.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use raypatch_engine::{Gpu, GpuOptions, Model, Output, Outputs, PipelineCacheDir, PipelineCacheStatus};

fn case(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/golden").join(name)
}

/// An empty folder of its own under the system's temporary folder.
fn temp_folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("raypatch-pipeline-cache-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn gpu_on(dir: &Path) -> Arc<Gpu> {
    let options = GpuOptions { pipeline_cache: PipelineCacheDir::Dir(dir.to_path_buf()), ..Default::default() };
    Arc::new(Gpu::new(&options).expect("no GPU adapter"))
}

/// Loads, encodes and renders the golden RP-SRT case on `gpu` (compiling its pipelines); the rgb.
fn render(gpu: &Arc<Gpu>) -> Vec<f32> {
    let model = Model::load(gpu.clone(), case("rpsrt_k4").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(case("rpsrt_k4").join("scene.safetensors")).unwrap();
    let frame = model.encode(&scene.inputs).unwrap().render(&scene.targets, Outputs::default()).unwrap();
    frame.get(Output::Rgb).expect("rgb").to_vec()
}

/// The cache file of `gpu`, or `None` (after saying why on stderr) when its adapter has no pipeline cache.
fn cache_file(gpu: &Gpu) -> Option<PathBuf> {
    match gpu.pipeline_cache_status() {
        PipelineCacheStatus::File { path, .. } => Some(path),
        PipelineCacheStatus::Unavailable(why) => {
            eprintln!("{}: no pipeline cache ({why}); checking the reason only", gpu.describe());
            assert!(!why.is_empty());
            assert!(gpu.features.is_empty() || !gpu.device.features().contains(wgpu_pipeline_cache()));
            None
        }
    }
}

fn wgpu_pipeline_cache() -> raypatch_engine::wgpu::Features {
    raypatch_engine::wgpu::Features::PIPELINE_CACHE
}

fn read_bytes(gpu: &Gpu) -> u64 {
    match gpu.pipeline_cache_status() {
        PipelineCacheStatus::File { read_bytes, .. } => read_bytes,
        PipelineCacheStatus::Unavailable(why) => panic!("the pipeline cache went away: {why}"),
    }
}

#[test]
fn compiled_pipelines_are_written_and_read_by_the_next_gpu() {
    let dir = temp_folder("written");
    let gpu = gpu_on(&dir);
    let rgb = render(&gpu);
    assert!(gpu.counters().pipelines_compiled > 0);
    assert!(gpu.counters().pipeline_compile_nanos > 0);
    let Some(file) = cache_file(&gpu) else {
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "a cache file without a pipeline cache");
        return;
    };
    assert!(file.starts_with(&dir), "{} is outside {}", file.display(), dir.display());
    assert_eq!(read_bytes(&gpu), 0, "a fresh folder has no cache to read");
    assert!(gpu.save_pipeline_cache().unwrap(), "new pipelines were not written");
    let written = std::fs::read(&file).unwrap();
    assert!(!written.is_empty());
    // Nothing compiled since: nothing to write.
    assert!(!gpu.save_pipeline_cache().unwrap());
    drop(gpu);
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "temporary files were left behind");

    let again = gpu_on(&dir);
    assert_eq!(read_bytes(&again), written.len() as u64);
    assert_eq!(render(&again), rgb, "pipelines from the cache rendered other pixels");
    drop(again);
    assert!(!std::fs::read(&file).unwrap().is_empty());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn dropping_the_gpu_writes_the_cache() {
    let dir = temp_folder("dropped");
    let gpu = gpu_on(&dir);
    render(&gpu);
    let file = cache_file(&gpu);
    drop(gpu);
    if let Some(file) = file {
        assert!(std::fs::metadata(&file).unwrap().len() > 0, "{} is empty", file.display());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_cache_files_start_the_cache_empty() {
    let dir = temp_folder("bad");
    let probe = gpu_on(&dir);
    let Some(file) = cache_file(&probe) else {
        return;
    };
    let rgb = render(&probe);
    drop(probe);
    let good = std::fs::read(&file).unwrap();
    assert!(good.len() > 32, "a cache of {} bytes", good.len());

    let garbage: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
    let mut with_magic = good[..8].to_vec();
    with_magic.extend_from_slice(&garbage);
    let mut truncated = good.clone();
    truncated.truncate(good.len() / 2);
    // Bytes 17..32 of wgpu's header name the adapter: a cache of another adapter, which wgpu refuses even
    // with `fallback`.
    let mut other_adapter = good.clone();
    other_adapter[20] ^= 0x5a;
    for (what, bytes, read) in [
        ("garbage", &garbage, 0),
        ("an empty file", &Vec::new(), 0),
        ("garbage after wgpu's magic", &with_magic, with_magic.len() as u64),
        ("a truncated cache", &truncated, truncated.len() as u64),
        ("another adapter's cache", &other_adapter, 0),
    ] {
        std::fs::write(&file, bytes).unwrap();
        let gpu = gpu_on(&dir);
        assert_eq!(read_bytes(&gpu), read, "{what}");
        assert_eq!(render(&gpu), rgb, "{what}: other pixels");
        drop(gpu);
        let replaced = std::fs::read(&file).unwrap();
        assert!(replaced.starts_with(b"WGPUPLCH"), "{what} was not replaced by a wgpu pipeline cache");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_cache_turned_off_writes_nothing() {
    let gpu = Arc::new(
        Gpu::new(&GpuOptions { pipeline_cache: PipelineCacheDir::Off, ..Default::default() }).expect("no GPU adapter"),
    );
    render(&gpu);
    assert_eq!(gpu.pipeline_cache_status(), PipelineCacheStatus::Unavailable("turned off".into()));
    assert!(!gpu.save_pipeline_cache().unwrap());
    assert!(gpu.counters().pipeline_compile_nanos > 0);
}

#[test]
fn an_unwritable_cache_folder_is_not_fatal() {
    let dir = temp_folder("unwritable");
    // The cache folder would be inside a file: creating it fails.
    let blocker = dir.join("file");
    std::fs::write(&blocker, b"not a folder").unwrap();
    let gpu = gpu_on(&blocker.join("cache"));
    render(&gpu);
    if cache_file(&gpu).is_some() {
        assert!(gpu.save_pipeline_cache().is_err());
    }
    drop(gpu); // logs the error once, does not panic
    std::fs::remove_dir_all(&dir).unwrap();
}
