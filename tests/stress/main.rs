//! The numerical stress suite: every case against a float64 reference with a stated tolerance, and NaN or
//! infinity never passing (every comparison treats a non-finite value as an infinite error).
//!
//! Model level, here:
//! - `reference`: the float64 CPU reference of the whole model (`reference::model`) against float64 PyTorch
//!   runs of the official model, and the engine against it, on every golden case;
//! - `cameras`: cameras up to 1e3 away, looking from near the poles of the look-at frame, rays along the axes;
//! - `f16`: f16 weight storage against the float64 reference; weights beyond f16's range keep their layer in
//!   f32 (reported), never infinity;
//! - `long_runs`: 1,000 renders of one scene give the same bytes and allocate nothing after the first.
//!
//! Kernel level, in the kernels test binary (`cargo test --release --test kernels`), next to the kernels'
//! other tests so that their harnesses are not copied:
//! - attention with logits up to ±1e4, one dominant key, flat rows, 16384 keys: `tests/kernels/attention.rs`
//!   (`attention_large_exact_logits`, `attention_large_random_logits`, `attention_dominant_key_and_flat_rows`,
//!   `attention_long_kv`, `attention_long_kv_large_logits`);
//! - layernorm of rows with mean 1e4 and standard deviation 1e-2, and constant rows: `tests/kernels/norm.rs`
//!   (`layernorm_large_mean_small_spread`, `layernorm_constant_rows_give_beta`);
//! - the Fourier encoding at every octave up to 2^14·π for coordinates up to |10|, against f64 sin/cos of the
//!   same f32 argument: `tests/kernels/posenc.rs` (`fourier_encode_every_octave`,
//!   `fourier_encode_dense_argument_sweep`), and of camera positions up to 1e3 away:
//!   `fourier_encode_far_camera_positions`.

#[path = "../common/mod.rs"]
#[allow(unused_imports)]
mod common;

mod cameras;
mod f16;
mod long_runs;
mod reference;

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock, RwLock, RwLockReadGuard, RwLockWriteGuard};

use raypatch_engine::{Gpu, GpuOptions, Model};
use raypatch_model::LoadedModel;

/// The adapter the whole binary shares (a real GPU if there is one, lavapipe otherwise).
fn gpu() -> Arc<Gpu> {
    static GPU: OnceLock<Arc<Gpu>> = OnceLock::new();
    GPU.get_or_init(|| {
        let gpu = Gpu::new(&GpuOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)");
        eprintln!("stress tests run on {}", gpu.describe());
        Arc::new(gpu)
    })
    .clone()
}

/// The process's resident memory is shared by the tests of this binary, which run in parallel: `long_runs`
/// measures it alone (a write guard) while every other test holds a read guard.
static MEMORY: RwLock<()> = RwLock::new(());

fn sharing_memory() -> RwLockReadGuard<'static, ()> {
    MEMORY.read().unwrap_or_else(|e| e.into_inner())
}

fn measuring_memory() -> RwLockWriteGuard<'static, ()> {
    MEMORY.write().unwrap_or_else(|e| e.into_inner())
}

fn golden_case(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/golden").join(name)
}

fn engine_model(loaded: &LoadedModel) -> Model {
    Model::from_loaded(gpu(), loaded).unwrap_or_else(|e| panic!("{}: {e}", loaded.path))
}
