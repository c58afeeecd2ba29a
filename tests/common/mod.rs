//! Shared test helpers: one GPU for the whole test binary, single-op plans, and error measures.
#![allow(dead_code)]

use std::sync::OnceLock;

use raypatch_engine::plan::{Plan, PlanBuilder};
use raypatch_engine::{Gpu, GpuOptions};

pub use raypatch_engine::reference::Rng;

/// The adapter every test in this binary shares (a real GPU if there is one, lavapipe otherwise).
pub fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| {
        let gpu = Gpu::new(&GpuOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)");
        eprintln!("tests run on {}", gpu.describe());
        gpu
    })
}

/// Builds a plan, executes it once, and waits for it.
pub fn run(builder: PlanBuilder) -> Plan {
    let gpu = gpu();
    let plan = builder.build(gpu).expect("plan build");
    plan.execute(gpu);
    plan
}

/// Largest |a - b| over two slices of equal length; infinite if either holds a NaN or infinity.
pub fn max_abs_diff(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "length mismatch");
    a.iter()
        .zip(b)
        .map(|(&x, &y)| if x.is_finite() && y.is_finite() { (x as f64 - y).abs() } else { f64::INFINITY })
        .fold(0.0, f64::max)
}

/// Asserts max |gpu - reference| <= atol + rtol * max |reference|, with a message naming the case.
pub fn assert_close(what: &str, gpu: &[f32], reference: &[f64], atol: f64, rtol: f64) {
    let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = max_abs_diff(gpu, reference);
    let tol = atol + rtol * scale;
    assert!(err <= tol, "{what}: max abs error {err:e} > tolerance {tol:e} (max |ref| {scale:e})");
}
