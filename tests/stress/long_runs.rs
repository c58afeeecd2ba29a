//! Long runs: 1,000 renders of one scene (the smallest golden case) give identical bytes each time, and the
//! engine creates no buffer, allocates no byte and compiles no pipeline after the first render. The process's
//! resident memory is also watched, to catch leaks outside the engine's counters (readback buffers, driver
//! objects).

use std::sync::Arc;

use raypatch_engine::{Gpu, GpuOptions, Model, Output, Outputs};

use crate::golden_case;

const RENDERS: usize = 1000;
/// Resident-memory growth allowed between render 100 and render 1,000: each render reads back ~18 KiB, so a
/// leak of anything per render would pass 16 MiB; allocator noise stays far below.
const RSS_SLACK_BYTES: u64 = 16 << 20;

/// The resident set size of this process (Linux `/proc/self/statm`), when available.
fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

#[test]
fn a_thousand_renders_are_identical_and_allocate_nothing() {
    let _memory = crate::measuring_memory();
    let loaded = raypatch_model::load_model(golden_case("rpsrt_k8").join("model.safetensors")).unwrap();
    let scene = raypatch_model::load_scene(golden_case("rpsrt_k8").join("scene.safetensors")).unwrap();
    // A GPU of its own: the other tests of this binary run in parallel and would move the shared counters.
    let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter"));
    let model = Model::from_loaded(gpu.clone(), &loaded).unwrap();
    let encoded = model.encode(&scene.inputs).unwrap();
    let first = encoded.render(&scene.targets, Outputs::default()).unwrap().take(Output::Rgb).expect("rgb");
    assert!(first.iter().all(|v| v.is_finite()), "non-finite rgb");
    let after_first = gpu.counters();
    let mut rss_at_100 = None;
    for i in 1..RENDERS {
        let rgb = encoded.render(&scene.targets, Outputs::default()).unwrap().take(Output::Rgb).expect("rgb");
        // Bit-for-bit: compare the bits, so that NaNs could not compare unequal to themselves unnoticed.
        let same = rgb.len() == first.len() && rgb.iter().zip(&first).all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "render {i} differs from the first");
        if i == 100 {
            rss_at_100 = resident_bytes();
        }
    }
    let end = gpu.counters();
    assert_eq!(end.buffers_created, after_first.buffers_created, "buffers were created after the first render");
    assert_eq!(end.bytes_allocated, after_first.bytes_allocated, "bytes were allocated after the first render");
    assert_eq!(
        end.pipelines_compiled, after_first.pipelines_compiled,
        "pipelines were compiled after the first render"
    );
    assert_eq!(end.submits - after_first.submits, (RENDERS - 1) as u64, "a render is one submit");
    assert_eq!(encoded.cached_render_plans(), 1);
    if let (Some(before), Some(after)) = (rss_at_100, resident_bytes()) {
        eprintln!(
            "resident memory: {:.1} MiB at render 100, {:.1} MiB at render {RENDERS}",
            before as f64 / 1048576.0,
            after as f64 / 1048576.0
        );
        assert!(after <= before + RSS_SLACK_BYTES, "resident memory grew from {before} to {after} bytes");
    }
}
