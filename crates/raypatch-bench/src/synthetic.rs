//! Models and scenes made in memory, so that the harness and the stress tests need no files and no PyTorch:
//! random weights for any config (the official full-size ones included, as `tools/data/make_golden.py` makes
//! them) and scenes seen by MSN-Easy cameras (`tools/reference/cameras.py`).

use raypatch_engine::EngineError;
use raypatch_model::pinhole::{Intrinsics, PinholeRays, MSN_FOCAL_LENGTH as FOCAL, MSN_SENSOR_WIDTH as SENSOR_WIDTH};
use raypatch_model::{
    official, InputViews, LoadedModel, ModelConfig, ModelError, RayKind, TargetRays, TargetViews, TensorFile,
    MODEL_FORMAT,
};
use raypatch_reference::Rng;
use safetensors::tensor::TensorView;
use safetensors::Dtype;
use serde_json::{json, Value};

/// The model section of the official MSN-Easy `srt_MDBN_32` run ([`official::config`]).
pub fn official_srt_config() -> Value {
    official::config("srt_MDBN_32")
}

/// The official MSN-Easy `rpsrt_MDBN_4_32` run with patch size `k` (a power of two; the official run has 4): the
/// `srt_MDBN_32` model with the Ray-Patch decoder, whose feature width the checkpoint stores as `out_dims`.
pub fn official_rpsrt_config(k: usize) -> Value {
    assert!(k.is_power_of_two() && k > 1, "Ray-Patch k must be a power of two above 1");
    let mut cfg = official::config("rpsrt_MDBN_4_32");
    cfg["decoder_kwargs"]["out_dims"] = json!(128);
    cfg["rp_kwargs"]["upsample"] = json!(k.trailing_zeros());
    (cfg["rp_kwargs"]["h_in"], cfg["rp_kwargs"]["w_in"]) = (json!(120 / k), json!(160 / k));
    cfg
}

/// The official MSN-Easy OSRT run `osrt_MDBN_64`: 5 slots 1536 wide, the slot mixer's 1536-wide widths, a per-pixel
/// light field (95 M parameters).
pub fn official_osrt_config() -> Value {
    official::config("osrt_MDBN_64")
}

/// The official MSN-Easy RP-OSRT run `rposrt_MDBN_8_64`: the OSRT model with the Ray-Patch decoder, k = 8 (15x20
/// patch rays for 120x160 targets).
pub fn official_rposrt_config() -> Value {
    official::config("rposrt_MDBN_8_64")
}

/// The official ScanNet DeFiNe runs (`define_32_stereo_acc` for k = 1, `rpdefine_16_32_stereo_acc` for k = 16):
/// ResNet-18 and a Perceiver IO of 2048 latents of 512 (31 M parameters), rgb and depth heads.
pub fn official_define_config(k: usize) -> Value {
    match k {
        1 => official::config("define_32_stereo_acc"),
        16 => official::config("rpdefine_16_32_stereo_acc"),
        _ => panic!("the official DeFiNe runs have k = 1 and 16"),
    }
}

/// The official structure at small widths, as `tools/data/make_golden.py`'s `small_config`: 3 conv blocks, 2 + 2
/// attention layers, 15 + 15 octaves, 4 heads, tokens `width` wide; Ray-Patch with patch size `k` when
/// `k > 1` (conv_features `2·width`, at least 2·k).
pub fn small_config(k: usize, width: usize) -> Value {
    let mut cfg = json!({
        "base": "srt",
        "encoder_kwargs": {"pos_start_octave": -5, "num_att_blocks": 2, "num_conv_blocks": 3, "norm": "Batch",
                           "latent_dim": width, "conv_hidden": width / 4, "token_dim": width, "heads": 4,
                           "dim_head": width / 4},
        "decoder": "lightfield",
        "decoder_kwargs": {"num_att_blocks": 2, "pos_octaves": 15, "ray_octaves": 15, "pos_start_octave": -5,
                           "ray_start_octave": 0, "latent_dim": width, "mode": "efficient", "out_dims": 3,
                           "heads": 4, "input_mlp_hidden": 24, "out_mlp_hidden": 48},
    });
    if k > 1 {
        assert!(k.is_power_of_two(), "Ray-Patch k must be a power of two");
        let features = (2 * width).max(2 * k);
        cfg["decoder"] = json!("featurefield");
        cfg["decoder_kwargs"]["out_dims"] = json!(features);
        cfg["rp_kwargs"] = json!({"upsample": k.trailing_zeros(), "conv_features": features, "norm": "Batch"});
    }
    cfg
}

/// Random weights for `config`, as `tools/data/make_golden.py` draws them: He-style normal weights (gain 1 for the
/// attention projections and the output layers, √2 before the (Leaky)ReLUs), biases N(0, 0.1²), norm scales
/// U(0.5, 1.5), BatchNorm statistics N(0, 0.2²) and U(0.5, 2). The model goes through the same safetensors
/// parsing and config checks as a file (its tensors are checked when the engine builds it). Returns the model
/// and its file bytes (for tools that need a file).
pub fn random_model(config: &Value, seed: u64, name: &str) -> Result<(LoadedModel, Vec<u8>), EngineError> {
    Ok(model_from_tensors(config, &random_tensors(config, seed, name)?, name)?)
}

/// The tensors of [`random_model`]: (official name, shape, data), the tensors the engine's model of `config`
/// reads ([`raypatch_engine::models::expected_tensors`]).
pub fn random_tensors(config: &Value, seed: u64, name: &str) -> Result<Vec<Tensor>, EngineError> {
    let resolved = ModelConfig::from_value(name, config.clone())?;
    let mut rng = Rng::new(seed);
    Ok(raypatch_engine::models::expected_tensors(&resolved)?
        .into_iter()
        .map(|(key, shape)| {
            let count: usize = shape.iter().product();
            let data: Vec<f32> = if key.ends_with("running_mean") {
                (0..count).map(|_| (0.2 * rng.normal()) as f32).collect()
            } else if key.ends_with("running_var") {
                rng.vec_f32(count, 0.5, 2.0)
            } else if key.ends_with(".bias") {
                (0..count).map(|_| (0.1 * rng.normal()) as f32).collect()
            } else if shape.len() == 1 {
                rng.vec_f32(count, 0.5, 1.5)
            } else if key.ends_with("initial_slots") {
                (0..count).map(|_| rng.normal() as f32).collect()
            } else {
                let fan_in: usize = shape[1..].iter().product();
                let gain = if unit_gain(&key) { 1.0 } else { std::f64::consts::SQRT_2 };
                let std = gain / (fan_in as f64).sqrt();
                (0..count).map(|_| (std * rng.normal()) as f32).collect()
            };
            (key, shape, data)
        })
        .collect())
}

/// A model from its config and tensors, through a safetensors file in memory (returned too).
pub fn model_from_tensors(
    config: &Value,
    tensors: &[Tensor],
    name: &str,
) -> Result<(LoadedModel, Vec<u8>), ModelError> {
    let metadata = [
        ("format".to_string(), MODEL_FORMAT.to_string()),
        ("config".to_string(), config.to_string()),
        ("source".to_string(), format!("{name}, made in memory by raypatch-bench")),
    ];
    let bytes = serialize(tensors, metadata.into_iter().collect())
        .map_err(|reason| ModelError::Format { path: name.to_string(), reason })?;
    let model = raypatch_model::weights::model_from_file(TensorFile::parse(name, &bytes)?)?;
    Ok((model, bytes))
}

/// A named f32 tensor: (name, shape, row-major data).
pub type Tensor = (String, Vec<usize>, Vec<f32>);

/// Attention projections keep the logits O(1) (for OSRT also slot attention's and the mixing block's keys and
/// values, and the GRU cell, as make_golden.py's `randomize_osrt_weights`); output layers (no calibration
/// here, unlike make_golden.py) keep the pre-sigmoid outputs O(1), so that few pixels saturate. Everything
/// else feeds a (Leaky)ReLU. OSRT's initial slots are N(0, 1), as make_golden.py draws them.
fn unit_gain(key: &str) -> bool {
    let rgb_conv = key
        .strip_prefix("decoder_rp.conv_decoder.conv_blocks.")
        .is_some_and(|rest| rest.split('.').count() == 3 && rest.ends_with(".1.weight"));
    ["to_q.", "to_k.", "to_v.", "to_kv.", "to_qkv.", "to_out.", "gru.weight_"].iter().any(|p| key.contains(p))
        || key == "decoder_att.out_mlp.8.weight"
        || key == "decoder_att.render_mlp.net.8.weight"
        || key == "decoder_rp.conv_decoder.conv_0.weight"
        || rgb_conv
}

/// A safetensors file of f32 tensors (name, shape, data) with metadata.
pub fn serialize(tensors: &[Tensor], metadata: std::collections::HashMap<String, String>) -> Result<Vec<u8>, String> {
    let bytes: Vec<(&str, Vec<usize>, &[u8])> =
        tensors.iter().map(|(k, s, d)| (k.as_str(), s.clone(), bytemuck::cast_slice(d))).collect();
    let views = bytes
        .iter()
        .map(|(k, s, d)| TensorView::new(Dtype::F32, s.clone(), d).map(|v| (*k, v)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    safetensors::serialize(views, Some(metadata)).map_err(|e| e.to_string())
}

/// A camera centre on the sphere of radius `distance` around the origin (`tools/reference/cameras.py`
/// `look_at_positions`): azimuth in the xy plane from +x towards +y, elevation towards +z, in degrees.
pub fn look_at_position(azimuth_deg: f64, distance: f64, elevation_deg: f64) -> [f32; 3] {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    [(distance * e.cos() * a.cos()) as f32, (distance * e.cos() * a.sin()) as f32, (distance * e.sin()) as f32]
}

/// The MSN look-at frame of a camera at `position` looking at the origin with +z up, as columns: right, down,
/// forward (the official `get_camera_rays`'s horizontal, vertical and direction). A camera on the z axis has
/// no look-at frame.
fn look_at_frame(position: [f32; 3]) -> Result<[[f64; 3]; 3], String> {
    let c = position.map(f64::from);
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let scale = |v: [f64; 3], s: f64| v.map(|x| x * s);
    let cross =
        |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let dir = scale(c, -1.0 / norm(c));
    let horizontal = cross(dir, [0.0, 0.0, 1.0]);
    if norm(horizontal) < 1e-9 {
        return Err(format!("camera at {position:?} looks along the world up axis: no look-at frame"));
    }
    let horizontal = scale(horizontal, 1.0 / norm(horizontal));
    let vertical = cross(dir, horizontal);
    Ok([horizontal, scale(vertical, 1.0 / norm(vertical)), dir])
}

/// Unit rays `[height, width, 3]` of a pinhole camera at `position` looking at the origin with +z up, through
/// the pixel centres, row 0 at the top: the official `get_camera_rays` (focal 0.035, sensor width 0.032),
/// computed in f64 and rounded to f32 like the official loader.
pub fn camera_rays(position: [f32; 3], width: usize, height: usize) -> Result<Vec<f32>, String> {
    let [horizontal, vertical, dir] = look_at_frame(position)?;
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let sensor_height = SENSOR_WIDTH / width as f64 * height as f64;
    // Pixel centres: the midpoints of linspace(-1, 1, n + 1) · sensor / 2.
    let centre = |i: usize, n: usize, sensor: f64| (-1.0 + (2 * i + 1) as f64 / n as f64) * sensor / 2.0;
    let mut rays = Vec::with_capacity(width * height * 3);
    for y in 0..height {
        let v = centre(y, height, sensor_height);
        for x in 0..width {
            let h = centre(x, width, SENSOR_WIDTH);
            let ray: [f64; 3] = std::array::from_fn(|i| h * horizontal[i] + v * vertical[i] + dir[i] * FOCAL);
            let n = norm(ray);
            rays.extend(ray.map(|r| (r / n) as f32));
        }
    }
    Ok(rays)
}

/// The same camera as [`camera_rays`]'s, as a pinhole camera whose rays a render makes on the GPU (within one
/// float32 rounding of those).
pub fn look_at_camera(position: [f32; 3], width: usize, height: usize) -> Result<PinholeRays, String> {
    Ok(PinholeRays::new(
        RayKind::UnitDirection,
        &Intrinsics::msn(width, height),
        look_at_frame(position)?,
        position.map(f64::from),
    ))
}

/// A smooth colour image `[height, width, 3]` in [0, 1] with a few flat discs (like make_golden's images).
pub fn structured_image(height: usize, width: usize, rng: &mut Rng) -> Vec<f32> {
    let waves: Vec<(f64, f64, f64)> =
        (0..3).map(|_| (rng.uniform(0.3, 1.2), rng.uniform(0.3, 1.2), rng.uniform(0.0, 6.3))).collect();
    let discs: Vec<(f64, f64, f64, [f64; 3])> = (0..3)
        .map(|_| {
            (
                rng.uniform(0.15, 0.85),
                rng.uniform(0.15, 0.85),
                rng.uniform(0.08, 0.25),
                [rng.unit(), rng.unit(), rng.unit()],
            )
        })
        .collect();
    let mut image = Vec::with_capacity(height * width * 3);
    for y in 0..height {
        let fy = y as f64 / (height.max(2) - 1) as f64;
        for x in 0..width {
            let fx = x as f64 / (width.max(2) - 1) as f64;
            let disc = discs.iter().find(|(cy, cx, r, _)| (fy - cy).powi(2) + (fx - cx).powi(2) < r * r);
            for (c, (a, b, phase)) in waves.iter().enumerate() {
                let v = disc.map_or(0.5 + 0.25 * (std::f64::consts::TAU * (a * fx + b * fy) + phase).sin(), |d| d.3[c]);
                image.push(v.clamp(0.0, 1.0) as f32);
            }
        }
    }
    image
}

/// Where a scene's cameras are: on spheres around the origin, `distance` away, at these elevations (degrees).
#[derive(Clone, Debug)]
pub struct CameraRig {
    pub distance: (f64, f64),
    pub elevation: (f64, f64),
}

impl Default for CameraRig {
    /// MSN-Easy-like: 5 to 12 units away, 10° to 60° above the ground plane.
    fn default() -> Self {
        CameraRig { distance: (5.0, 12.0), elevation: (10.0, 60.0) }
    }
}

/// A scene: `inputs` views of `input_size` and `targets` target cameras of `target_size` (pinhole cameras,
/// whose rays a render makes on the GPU, as for the API's cameras), cameras placed by `rig`.
pub fn synthetic_scene(
    seed: u64,
    inputs: usize,
    input_size: (usize, usize),
    targets: usize,
    target_size: (usize, usize),
    rig: &CameraRig,
) -> Result<(InputViews, TargetViews), String> {
    let mut rng = Rng::new(seed);
    let camera = |rng: &mut Rng| {
        look_at_position(
            rng.uniform(0.0, 360.0),
            rng.uniform(rig.distance.0, rig.distance.1),
            rng.uniform(rig.elevation.0, rig.elevation.1),
        )
    };
    let (h, w) = input_size;
    let (mut images, mut positions, mut rays) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..inputs {
        let p = camera(&mut rng);
        images.extend(structured_image(h, w, &mut rng));
        rays.extend(camera_rays(p, w, h)?);
        positions.extend(p);
    }
    let input = InputViews { count: inputs, height: h, width: w, images, camera_pos: positions, rays };
    let (th, tw) = target_size;
    let (mut positions, mut cameras) = (Vec::new(), Vec::new());
    for _ in 0..targets {
        let p = camera(&mut rng);
        cameras.push(look_at_camera(p, tw, th)?);
        positions.extend(p);
    }
    let target = TargetViews {
        count: targets,
        camera_pos: positions,
        rays: TargetRays::Pinhole(cameras),
        rays_height: th,
        rays_width: tw,
        declared_size: Some(target_size),
        images: None,
        masks: None,
    };
    Ok((input, target))
}

/// A scene file (docs/FORMATS.md) of these views, for PyTorch.
pub fn scene_file(inputs: &InputViews, targets: &TargetViews) -> Result<Vec<u8>, String> {
    let (n, h, w) = (inputs.count, inputs.height, inputs.width);
    let t = targets.count;
    let (th, tw) = (targets.rays_height, targets.rays_width);
    let tensors = vec![
        ("input_images".to_string(), vec![n, h, w, 3], inputs.images.clone()),
        ("input_camera_pos".to_string(), vec![n, 3], inputs.camera_pos.clone()),
        ("input_rays".to_string(), vec![n, h, w, 3], inputs.rays.clone()),
        ("target_camera_pos".to_string(), vec![t, 3], targets.camera_pos.clone()),
        ("target_rays".to_string(), vec![t, th, tw, 3], targets.ray_values().into_owned()),
    ];
    let metadata = json!({"format": "raypatch-scene/1"});
    let metadata = metadata
        .as_object()
        .expect("object")
        .iter()
        .map(|(k, v)| (k.clone(), v.as_str().unwrap_or_default().to_string()))
        .collect();
    serialize(&tensors, metadata)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The golden scenes' target rays were made by tools/reference/cameras.py from their camera positions.
    #[test]
    fn camera_rays_match_tools_cameras_py() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/golden");
        for case in ["srt_k1", "rpsrt_k4"] {
            let scene = raypatch_model::load_scene(dir.join(case).join("scene.safetensors")).unwrap();
            let t = &scene.targets;
            let (per_view, values) = (t.rays_height * t.rays_width * 3, t.ray_values());
            for v in 0..t.count {
                let position = [t.camera_pos[3 * v], t.camera_pos[3 * v + 1], t.camera_pos[3 * v + 2]];
                let rays = camera_rays(position, t.rays_width, t.rays_height).unwrap();
                let want = &values[v * per_view..(v + 1) * per_view];
                // numpy sums the pixel offsets in another order: allow one f32 rounding step (2^-24 relative).
                let err = rays.iter().zip(want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
                assert!(err <= 1.2e-7, "{case} view {v}: rays differ from tools/reference/cameras.py by {err:e}");
            }
        }
    }

    /// The benchmark's target cameras are the look-at cameras of `camera_rays`, their rays made as the GPU
    /// makes them: within one float32 rounding of the official rays.
    #[test]
    fn look_at_cameras_give_the_official_rays() {
        for (position, (w, h)) in [([4.0, -3.0, 2.5], (16, 12)), ([-1.5, 0.2, 9.0], (7, 5))] {
            let official = camera_rays(position, w, h).unwrap();
            let camera = &look_at_camera(position, w, h).unwrap();
            let ours: Vec<f32> = (0..h).flat_map(|i| (0..w).flat_map(move |j| camera.ray(i, j))).collect();
            let err = ours.iter().zip(&official).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(err <= 1.2e-7, "{position:?}: {err:e}");
        }
    }

    #[test]
    fn a_camera_on_the_up_axis_has_no_frame() {
        assert!(camera_rays([0.0, 0.0, 5.0], 4, 3).is_err());
        let near = camera_rays(look_at_position(30.0, 1e3, 89.999), 4, 3).unwrap();
        assert!(near.chunks(3).all(|r| ((r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) - 1.0).abs() < 1e-6 && r[2] < -0.9));
    }

    #[test]
    fn random_models_load_for_every_config() {
        for (k, config) in [(1, small_config(1, 16)), (4, small_config(4, 16)), (16, small_config(16, 32))] {
            let (model, bytes) = random_model(&config, 1, "small").unwrap();
            assert_eq!(model.config.patch_size(), k);
            assert!(bytes.len() > 4 * model.parameter_count());
            // The engine's module tree reads every tensor, of its shape, and nothing is left over.
            raypatch_engine::models::build(&model, raypatch_engine::nn::ReadLimits::NONE).unwrap();
        }
        let official = ModelConfig::from_value("srt", official_srt_config()).unwrap();
        let srt = official.srt().unwrap();
        assert_eq!((srt.encoder.token_dim, srt.decoder.out_mlp_hidden), (768, 1536));
        let rp = ModelConfig::from_value("rpsrt", official_rpsrt_config(8)).unwrap();
        assert_eq!((rp.patch_size(), rp.srt().unwrap().decoder.out_dims), (8, 128));
    }

    /// The official OSRT configs resolve to the official run's widths (the tensors' names and shapes are
    /// checked against the official state_dict by the engine's tests/official_keys.rs).
    #[test]
    fn official_osrt_configs() {
        for (config, k, out_dims) in [(official_osrt_config(), 1, 3), (official_rposrt_config(), 8, 128)] {
            let resolved = ModelConfig::from_value("osrt", config).unwrap();
            let raypatch_model::Family::Osrt(c) = &resolved.family else { panic!("not an OSRT config") };
            assert_eq!(resolved.patch_size(), k);
            assert_eq!(
                (c.slot_attention.num_slots, c.slot_attention.slot_dim, c.decoder.allocation.heads),
                (5, 1536, 12)
            );
            assert_eq!((c.decoder.render_hidden, c.decoder.out_dims), (1536, out_dims));
        }
    }
}
