//! Cameras far from the scene and cameras near the poles of the look-at frame, on golden models: the engine
//! against the float64 reference with the encoding arguments rounded to f32 as torch float32 rounds them.
//!
//! A camera 1e3 away makes the top position octave (2^9·π) an argument of ~1.6e6, where an f32 ulp is 0.125:
//! the float32 model (torch's, and the engine's) sees a phase that far from the float64 one, so the
//! comparison with the float64-argument model is printed, not asserted. Near the poles (elevation within
//! 0.01° of ±90°) the look-at frame is nearly degenerate and the rays point nearly along ∓z.

use raypatch_bench::synthetic::{synthetic_scene, CameraRig};
use raypatch_engine::{Output, Outputs};
use raypatch_reference::model::{Argument, ReferenceModel};

use crate::common::max_abs_diff;
use crate::{engine_model, golden_case};

/// As for the golden cases (f32 arithmetic through ~10 layers). The sin/cos of the far positions' arguments
/// (above the 2^20 up to which the kernel states 1.2e-7) stay within 2.5e-7 (kernels test
/// `fourier_encode_far_camera_positions`), which the network does not amplify past this.
const TOL: f64 = 1e-4;

#[test]
fn far_and_polar_cameras_match_the_reference() {
    let _memory = crate::sharing_memory();
    let rigs = [
        ("1e3 away", CameraRig { distance: (900.0, 1000.0), elevation: (-60.0, 60.0) }),
        ("100 away", CameraRig { distance: (90.0, 100.0), elevation: (10.0, 60.0) }),
        ("near the north pole", CameraRig { distance: (5.0, 12.0), elevation: (89.99, 89.999) }),
        ("near the south pole", CameraRig { distance: (5.0, 12.0), elevation: (-89.999, -89.99) }),
        ("near the pole, 1e3 away", CameraRig { distance: (900.0, 1000.0), elevation: (89.99, 89.999) }),
    ];
    for case in ["srt_k1", "rpsrt_k4"] {
        let loaded = raypatch_model::load_model(golden_case(case).join("model.safetensors")).unwrap();
        let model = engine_model(&loaded);
        let reference = ReferenceModel::new(&loaded, Argument::RoundedToF32).unwrap();
        let float64 = ReferenceModel::new(&loaded, Argument::Float64).unwrap();
        for (seed, (what, rig)) in rigs.iter().enumerate() {
            let (inputs, targets) = synthetic_scene(seed as u64, 2, (24, 32), 2, (16, 24), rig).unwrap();
            let mut frame = model.encode(&inputs).unwrap().render(&targets, Outputs::default()).unwrap();
            let rgb = frame.take(Output::Rgb).expect("rgb");
            assert!(rgb.iter().all(|v| v.is_finite()), "{case}, cameras {what}: non-finite rgb");
            let want = reference.render(&reference.encode(&inputs).unwrap(), &targets).unwrap();
            let err = max_abs_diff(&rgb, &want.rgb);
            let exact = float64.render(&float64.encode(&inputs).unwrap(), &targets).unwrap();
            let model_gap = max_abs_diff(&rgb, &exact.rgb);
            eprintln!("{case}, cameras {what}: rgb error {err:.1e} (vs the float64-argument model: {model_gap:.1e})");
            assert!(err <= TOL, "{case}, cameras {what}: rgb error {err:e} > {TOL:e}");
        }
    }
}
