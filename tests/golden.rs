//! Parity with the official PyTorch model: every case in assets/golden (written by tools/data/make_golden.py)
//! is encoded and rendered on the GPU, on every matmul kernel the adapter runs, and compared with the latent
//! and rgb PyTorch computed.
//! Tolerances (issues #2, #11): max |rgb - rgb_torch| <= 1e-4 and the same for the segmentation (slot weights);
//! max |z - z_torch| / max |z_torch| <= 1e-4 for the latent (OSRT: the slots) and SRT's log-depth (its raw
//! fourth channel); DeFiNe's log-depth (the log of a depth in 0.1..10, issue #12) max abs <= 1e-4.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use raypatch::metrics::fg_ari;
use raypatch_engine::{Frame, Gpu, GpuOptions, LoadOptions, MatmulKernel, Model, Output, Outputs, Precision};
use raypatch_model::TensorFile;

const OUTPUT_MAX_ABS: f64 = 1e-4;
const LATENT_MAX_REL: f64 = 1e-4;

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/golden")
}

fn max_abs(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| if x.is_finite() { (x - y).abs() as f64 } else { f64::INFINITY }).fold(0.0, f64::max)
}

/// What a case must meet: max abs error of rgb, segmentation and DeFiNe's log-depth, relative error of the latent
/// and SRT's log-depth.
#[derive(Clone, Copy)]
struct Budget {
    output_max_abs: f64,
    latent_max_rel: f64,
}

/// f32: parity with PyTorch within f32 rounding.
const F32_BUDGET: Budget = Budget { output_max_abs: OUTPUT_MAX_ABS, latent_max_rel: LATENT_MAX_REL };

/// The tensor path (`Precision::F16Activations` on cooperative matrices: every GEMM's operands rounded to f16, sums
/// in f32). Measured on Mesa 26's lavapipe (8x8 tiles): rgb 2.3e-3 to 4.5e-3 on the Ray-Patch SRT and OSRT cases,
/// 6.3e-3 to 9.3e-3 on per-pixel SRT, 8.3e-3 to 1.9e-2 on DeFiNe (its 1146-wide Perceiver cross-attention logits);
/// segmentation up to 5.4e-3, DeFiNe's log-depth up to 1.9e-2, latents up to 3.6e-3 relative. The budget is 2.5e-2
/// abs (PyTorch's bf16 autocast: 2.6e-2 on RP-SRT) and 1e-2 relative: it catches a broken kernel, not a regression
/// of a few 1e-3, which the benchmark's accuracy columns track (issue 47 asks for 5e-3 on rgb: not met yet by
/// SRT and DeFiNe).
const TENSOR_BUDGET: Budget = Budget { output_max_abs: 2.5e-2, latent_max_rel: 1e-2 };

/// Encodes and renders one case and returns what is out of tolerance.
fn check_case(gpu: &Arc<Gpu>, dir: &Path) -> Vec<String> {
    check_case_at(gpu, dir, Precision::F32, F32_BUDGET)
}

/// [`check_case`] at `precision`, within `budget`.
fn check_case_at(gpu: &Arc<Gpu>, dir: &Path, precision: Precision, budget: Budget) -> Vec<String> {
    let Budget { output_max_abs, latent_max_rel } = budget;
    let name = dir.file_name().unwrap().to_string_lossy().into_owned();
    let loaded = raypatch_model::load_model(dir.join("model.safetensors")).unwrap_or_else(|e| panic!("{name}: {e}"));
    let model = Model::from_loaded_with(gpu.clone(), &loaded, &LoadOptions { precision })
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    if precision == Precision::F16Activations {
        assert_eq!(model.kernel_family(), MatmulKernel::Coop, "{name}: f16-act did not run on the tensor kernels");
    }
    let scene = raypatch_model::load_scene(dir.join("scene.safetensors")).unwrap_or_else(|e| panic!("{name}: {e}"));
    let expected = TensorFile::open(&dir.join("expected.safetensors")).unwrap_or_else(|e| panic!("{name}: {e}"));
    let bounded_log_depth = model.config.base() == "define";

    let start = Instant::now();
    let encoded = model.encode(&scene.inputs).unwrap_or_else(|e| panic!("{name}: {e}"));
    let encode_time = start.elapsed();
    let latent = gpu.read(&encoded.latent).unwrap();
    let want_latent = expected.f32("latent").unwrap();
    assert_eq!(want_latent.shape, vec![encoded.latent.rows, encoded.latent.cols], "{name}: latent shape");
    let scale = want_latent.data.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
    let latent_err = max_abs(&latent, &want_latent.data) / scale;

    // Every output the case holds; render twice: the second render reuses the plan and must give the same bytes.
    let outputs = Outputs::of(
        &[Output::Rgb, Output::LogDepth, Output::Segmentation]
            .into_iter()
            .filter(|o| expected.contains(o.name()))
            .collect::<Vec<_>>(),
    );
    let start = Instant::now();
    let frame = encoded.render(&scene.targets, outputs).unwrap_or_else(|e| panic!("{name}: {e}"));
    let first_render = start.elapsed();
    let start = Instant::now();
    let again = encoded.render(&scene.targets, outputs).unwrap();
    let warm_render = start.elapsed();
    for output in outputs.iter() {
        assert_eq!(frame.get(output), again.get(output), "{name}: a second {} render differs", output.title());
    }
    assert_eq!(encoded.cached_render_plans(), 1, "{name}: the second render built a new plan");

    // rgb and segmentation are in [0, 1]: absolute error. Log-depth is the raw pre-sigmoid channel: relative to
    // its magnitude like the latent.
    let mut errors = Vec::new();
    for output in outputs.iter() {
        let want = expected.f32(output.name()).unwrap();
        let got = frame.get(output).expect("requested");
        let channels = got.len() / (frame.views * frame.height * frame.width);
        let mut shape = vec![frame.views, frame.height, frame.width];
        if output != Output::LogDepth {
            shape.push(channels);
        }
        assert_eq!(want.shape, shape, "{name}: {} shape", output.title());
        let (err, tol, kind) = match output {
            Output::LogDepth if !bounded_log_depth => {
                let scale = want.data.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
                (max_abs(got, &want.data) / scale, latent_max_rel, "relative")
            }
            _ => (max_abs(got, &want.data), output_max_abs, "max abs"),
        };
        errors.push((output, err, tol, kind));
    }
    eprintln!(
        "{name}: latent rel err {latent_err:.2e}, {}; encode {:.1} ms, render {:.1} ms (first {:.1} ms), planned peak {:.2} MiB",
        errors.iter().map(|(o, e, _, kind)| format!("{} {kind} err {e:.2e}", o.title())).collect::<Vec<_>>().join(", "),
        encode_time.as_secs_f64() * 1e3,
        warm_render.as_secs_f64() * 1e3,
        first_render.as_secs_f64() * 1e3,
        encoded.render_stats(&scene.targets, outputs).unwrap().peak_bytes as f64 / (1 << 20) as f64
    );
    let mut failures = Vec::new();
    if expected.contains("fg_ari") {
        failures.extend(check_fg_ari(&name, &expected, &scene, &frame));
    }
    if latent_err > latent_max_rel {
        failures.push(format!("{name}: latent relative error {latent_err:e} > {latent_max_rel:e}"));
    }
    for (output, err, tol, kind) in errors {
        if err > tol {
            failures.push(format!("{name}: {} {kind} error {err:e} > {tol:e}", output.title()));
        }
    }
    failures
}

/// FG-ARI as the official code computes it: `raypatch::metrics::fg_ari` of PyTorch's own segmentation must give
/// its figure (to f64 rounding: the same contingency table), and of the engine's within 0.02 (a pixel whose two
/// largest slot weights differ by less than the float32 error may take the other slot).
fn check_fg_ari(name: &str, expected: &TensorFile, scene: &raypatch_model::SceneFile, frame: &Frame) -> Vec<String> {
    let want = expected.f64_values("fg_ari").unwrap()[0];
    let masks = scene.targets.masks.as_ref().expect("OSRT golden scenes hold target_masks");
    let torch = expected.f32("segmentation").unwrap();
    let slots = *torch.shape.last().unwrap();
    let of_torch = fg_ari(masks, &torch.data, slots).unwrap();
    let of_engine = fg_ari(masks, frame.get(Output::Segmentation).unwrap(), slots).unwrap();
    eprintln!(
        "{name}: FG-ARI {want:.6} (PyTorch), {of_torch:.6} (ours of PyTorch's segmentation), {of_engine:.6} (engine)"
    );
    let mut failures = Vec::new();
    if (of_torch - want).abs() > 1e-9 {
        failures.push(format!("{name}: FG-ARI of the PyTorch segmentation {of_torch} != official {want}"));
    }
    if (of_engine - want).abs() > 0.02 {
        failures.push(format!("{name}: FG-ARI of the engine's segmentation {of_engine} vs official {want}"));
    }
    failures
}

/// The folders of assets/golden that hold a case (an expected.safetensors), sorted.
fn golden_cases() -> Vec<PathBuf> {
    let mut cases: Vec<PathBuf> = std::fs::read_dir(golden_dir())
        .expect("assets/golden is missing: run python3 tools/data/make_golden.py --out assets/golden")
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("expected.safetensors").exists())
        .collect();
    cases.sort();
    cases
}

fn shared_gpu() -> Arc<Gpu> {
    Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter: install Mesa lavapipe (see .ci/run)"))
}

#[test]
fn golden_cases_match_pytorch() {
    let cases = golden_cases();
    let names: Vec<String> = cases.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    // The issue asks for SRT, every k, and a two-view case; make sure the assets still have them.
    for required in [
        "srt_k1",
        "rpsrt_k2",
        "rpsrt_k4",
        "rpsrt_k8",
        "rpsrt_k8_resize",
        "rpsrt_k16",
        "osrt",
        "osrt_iters3_ln",
        "rposrt_k8",
    ] {
        assert!(names.iter().any(|n| n == required), "golden case {required} is missing from assets/golden");
    }
    let mut failures = Vec::new();
    for kernel in MatmulKernel::ALL {
        if kernel == MatmulKernel::Coop {
            // Its f16 operands are outside the f32 tolerances: golden_cases_on_the_tensor_path has its budget.
            continue;
        }
        let gpu = match Gpu::new(&GpuOptions { matmul: Some(kernel), ..Default::default() }) {
            Ok(gpu) => Arc::new(gpu),
            Err(why) => {
                eprintln!("golden cases not run on {kernel:?}: {why}");
                continue;
            }
        };
        eprintln!("matmul kernel {kernel:?}:");
        failures.extend(cases.iter().flat_map(|dir| check_case(&gpu, dir)).map(|f| format!("{kernel:?}: {f}")));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Every golden case at the f16-act precision on the tensor kernels (cooperative matrices), where the device has
/// them (`.ci/coop.sh` runs it on Mesa 26's lavapipe), within [`TENSOR_BUDGET`].
#[test]
fn golden_cases_on_the_tensor_path() {
    let gpu = shared_gpu();
    if gpu.kernels.coop.is_none() {
        let why = gpu.without_coop.as_deref().unwrap_or("unknown");
        eprintln!("golden cases not run on the tensor kernels on {}: {why}", gpu.describe());
        return;
    }
    let cases = golden_cases();
    let failures: Vec<String> =
        cases.iter().flat_map(|dir| check_case_at(&gpu, dir, Precision::F16Activations, TENSOR_BUDGET)).collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The official full-size RP-SRT k=4 (768 wide, 5 encoder layers) at 60×80. Generate it first with
/// `python3 tools/data/make_golden.py --full-size --out target/golden-full`, then run
/// `cargo test --release --test golden -- --ignored --nocapture`.
/// Every registered family (`raypatch_model::FAMILY_BASES`) has golden cases, plain and Ray-Patch: a family
/// added without them fails here.
#[test]
fn every_family_has_golden_cases() {
    let mut have = Vec::new();
    for entry in std::fs::read_dir(golden_dir()).unwrap() {
        let model = entry.unwrap().path().join("model.safetensors");
        if model.exists() {
            let config = raypatch_model::load_model(&model).unwrap().config;
            have.push((config.base(), config.patch_size() > 1));
        }
    }
    for base in raypatch_model::FAMILY_BASES {
        for ray_patch in [false, true] {
            assert!(
                have.contains(&(base, ray_patch)),
                "no golden case of base {base}{}: add one to tools/data/make_golden.py (ARCHITECTURE.md, adding a family)",
                if ray_patch { " with Ray-Patch" } else { "" }
            );
        }
    }
}

#[test]
#[ignore = "needs target/golden-full from tools/data/make_golden.py --full-size (PyTorch)"]
fn full_size_rpsrt_k4_matches_pytorch() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/golden-full/rpsrt_k4_full");
    assert!(
        dir.join("expected.safetensors").exists(),
        "{} is missing: run python3 tools/data/make_golden.py --full-size --out target/golden-full",
        dir.display()
    );
    let failures = check_case(&shared_gpu(), &dir);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The top ray octave multiplies rays by 2^14·π, so a 1-ulp difference in a patch ray shows in the image:
/// the engine's patch rays must equal the ones the official loader makes, bit for bit.
#[test]
fn patch_rays_are_bit_exact() {
    use raypatch_engine::kernels::resize::{bilinear, ResizeArgs};
    use raypatch_engine::plan::PlanBuilder;

    let gpu = shared_gpu();
    let mut checked = 0;
    for entry in std::fs::read_dir(golden_dir()).unwrap() {
        let dir = entry.unwrap().path();
        let Ok(expected) = TensorFile::open(&dir.join("expected.safetensors")) else {
            continue;
        };
        if !expected.contains("patch_rays") {
            continue;
        }
        let scene = raypatch_model::load_scene(dir.join("scene.safetensors")).unwrap();
        let want = expected.f32("patch_rays").unwrap();
        let t = &scene.targets;
        let (ph, pw) = (want.shape[1], want.shape[2]);
        let mut b = PlanBuilder::new();
        let rays = b.input("rays", t.count * t.rays_height * t.rays_width, 3);
        let patch = b.output("patch_rays", t.count * ph * pw, 3);
        let (src, dst) = (b.all(rays), b.all(patch));
        let (n, from) = (t.count, (t.rays_height, t.rays_width));
        bilinear(&mut b, "patch_rays", ResizeArgs { x: src, n, from, out: dst, to: (ph, pw), accumulate: false });
        let plan = b.build(&gpu).unwrap();
        gpu.write(&plan.tensor(rays), &t.ray_values());
        plan.execute(&gpu);
        let got = gpu.read(&plan.tensor(patch)).unwrap();
        let differing = got.iter().zip(&want.data).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert_eq!(differing, 0, "{}: {differing} patch-ray components differ from PyTorch", dir.display());
        checked += 1;
    }
    assert!(checked >= 4, "expected Ray-Patch golden cases with patch_rays, found {checked}");
}
