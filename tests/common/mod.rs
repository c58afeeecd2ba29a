//! Shared test helpers: one GPU for the whole test binary, single-op plans, and error measures.
#![allow(dead_code)]

use std::sync::OnceLock;

use std::ops::Range;

use raypatch_engine::device::MatmulKernel;
use raypatch_engine::gpu::Shader;
use raypatch_engine::plan::{Plan, PlanBuilder};
use raypatch_engine::tensor::padded_cols;
use raypatch_engine::{wgpu, Gpu, GpuOptions, GpuTensor};

#[allow(unused_imports)]
pub use raypatch_reference::Rng;

/// The adapter every test in this binary shares (a real GPU if there is one, lavapipe otherwise).
pub fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| {
        let gpu = Gpu::new(&GpuOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)");
        eprintln!("tests run on {}", gpu.describe());
        gpu
    })
}

/// Every GEMM kernel (linear layers and convolutions) the test adapter runs, whichever the adapter would
/// pick by default: `Rows` and `Tiled` everywhere, `Lanes` where the adapter has 8-lane subgroups (lavapipe).
pub fn matmul_kernels() -> Vec<MatmulKernel> {
    let gpu = gpu();
    let lanes = MatmulKernel::Lanes.supported(&gpu.info, gpu.features);
    if let Err(why) = &lanes {
        eprintln!("matmul_lanes not tested on {}: {why}", gpu.describe());
    }
    [MatmulKernel::Rows, MatmulKernel::Tiled].into_iter().chain(lanes.ok().map(|_| MatmulKernel::Lanes)).collect()
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

pub fn to_f64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&a| f64::from(a)).collect()
}

/// A `[rows, cols]` output tensor filled with `sentinel` everywhere, padding included, so that a test can see
/// which elements a kernel wrote.
pub fn sentinel_tensor(rows: usize, cols: usize, sentinel: f32) -> GpuTensor {
    let ld = padded_cols(cols);
    let t = gpu().upload("out", rows, ld, &vec![sentinel; rows * ld]).expect("upload");
    GpuTensor { cols, ..t }
}

/// Reads back a [`sentinel_tensor`] after a kernel wrote rows `view`: asserts that the view's padding is zero
/// and that every other row still holds the sentinel, and returns the view's rows without padding.
pub fn read_written_rows(out: &GpuTensor, view: Range<usize>, sentinel: f32) -> Vec<f32> {
    let (cols, ld) = (out.cols, padded_cols(out.cols));
    let padded = gpu().read_rows(&out.buffer, 0, out.rows, ld).expect("read");
    let mut got = Vec::with_capacity(view.len() * cols);
    for (r, row) in padded.chunks(ld).enumerate() {
        if view.contains(&r) {
            got.extend_from_slice(&row[..cols]);
            assert!(row[cols..].iter().all(|&v| v == 0.0), "row {r}: padding not zeroed");
        } else {
            assert!(row.iter().all(|&v| v == sentinel), "row {r} outside the view was written");
        }
    }
    got
}

/// Parses and validates a WGSL source with naga, with the capabilities its optional wgpu features give
/// (f16, subgroups in compute shaders, cooperative matrices); panics naming the shader on any error.
pub fn validate_wgsl(name: &str, source: &str, features: wgpu::Features) -> (naga::Module, naga::valid::ModuleInfo) {
    let module =
        naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    let mut capabilities = naga::valid::Capabilities::empty();
    if features.contains(wgpu::Features::SHADER_F16) {
        capabilities |= naga::valid::Capabilities::SHADER_FLOAT16;
    }
    if features.contains(wgpu::Features::SUBGROUP) {
        capabilities |= naga::valid::Capabilities::SUBGROUP;
    }
    if features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
        capabilities |= naga::valid::Capabilities::COOPERATIVE_MATRIX;
    }
    let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities)
        .subgroup_stages(naga::valid::ShaderStages::COMPUTE)
        .subgroup_operations(naga::valid::SubgroupOperationSet::all())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {e:?}"));
    (module, info)
}

/// `base` with `from` replaced by `to` in its source, under a name of its own (pipelines are cached by name): a
/// broken kernel for the mutation checks, which must fail the test it is substituted into
/// (`PlanBuilder::substitute_shader`).
pub fn mutated(base: &'static Shader, from: &str, to: &str) -> &'static Shader {
    assert_eq!(base.source.matches(from).count(), 1, "{}: the mutation's text must occur once", base.name);
    let name = Box::leak(format!("{}_mutated_{}", base.name, from.len() * 31 + to.len()).into_boxed_str());
    let replace = [
        base.replace,
        &[(Box::leak(from.to_string().into_boxed_str()) as &str, Box::leak(to.to_string().into_boxed_str()) as &str)],
    ]
    .concat();
    Box::leak(Box::new(Shader { name, replace: Box::leak(replace.into_boxed_slice()), ..*base }))
}

/// Whether the adapter runs the tensor kernels (`MatmulKernel::Coop`); says why not where it does not.
pub fn coop_runs() -> bool {
    let gpu = gpu();
    match (&gpu.kernels.coop, &gpu.without_coop) {
        (Some(shape), _) => {
            eprintln!("tensor kernels: {}x{} tiles, {}-lane subgroups", shape.tile, shape.tile, shape.lanes);
            true
        }
        (None, why) => {
            eprintln!("tensor kernels not tested on {}: {}", gpu.describe(), why.as_deref().unwrap_or("unknown"));
            false
        }
    }
}

/// Runs `check` expecting it to fail on its values (a mutation check): the failure must be a wrong value (an
/// assert_close or an assertion on what was written), not a kernel that does not compile.
pub fn fails_on_values(what: &str, check: impl FnOnce()) {
    // The expected panic prints its message like any other (the panic hook is the process's, shared by the tests).
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(check));
    let payload = result.err().unwrap_or_else(|| panic!("{what}: the check passed"));
    let message = payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_default();
    let on_values = ["max abs error", "padding", "outside the view", "changed", "tolerance"];
    assert!(on_values.iter().any(|m| message.contains(m)), "{what}: failed, but not on its values: {message}");
}
