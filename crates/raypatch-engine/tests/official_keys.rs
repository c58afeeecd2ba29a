//! The module trees built from the official run configs (`raypatch_model::official`: SRT, RP-SRT, OSRT, RP-OSRT,
//! DeFiNe, RP-DeFiNe) fetch exactly the official state_dict names and shapes of `assets/official/keys/`, and hold
//! the official parameter counts (`models::expected_tensors`, no GPU).

use raypatch_engine::models::expected_tensors;
use raypatch_model::{official, Family, ModelConfig};
use serde_json::json;

/// Reads the official run's key list, `assets/official/keys/<run>.txt`: `name [d0, d1, ...]` per line.
fn official_keys(run: &str) -> Vec<(String, Vec<usize>)> {
    let path = format!("{}/../../assets/official/keys/{run}.txt", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|l| {
            let (name, shape) = l.split_once(' ').unwrap();
            let dims = shape.trim_matches(|c| c == '[' || c == ']');
            let dims = dims.split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse().unwrap()).collect();
            (name.to_string(), dims)
        })
        .filter(|(name, _)| !name.ends_with("num_batches_tracked"))
        .collect()
}

/// Checks the module tree of the official run `run` against its key list: the same names and shapes, and
/// `params` parameters (the header of shared/reference/official-state-dict-keys.txt: `model.parameters()`,
/// BatchNorm running statistics not counted).
fn check(run: &str, params: usize) {
    let config = ModelConfig::from_value(run, official::config(run)).unwrap();
    let mut ours = expected_tensors(&config).unwrap();
    let mut theirs = official_keys(run);
    let count = |keys: &[(String, Vec<usize>)]| {
        let trained = keys.iter().filter(|(name, _)| !name.ends_with("running_mean") && !name.ends_with("running_var"));
        trained.map(|(_, shape)| shape.iter().product::<usize>()).sum::<usize>()
    };
    assert_eq!(count(&theirs), params, "{run}: the key list does not hold the header's parameter count");
    ours.sort();
    theirs.sort();
    let names = |keys: &[(String, Vec<usize>)]| keys.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    let (our_names, their_names) = (names(&ours), names(&theirs));
    let missing: Vec<_> = their_names.iter().filter(|n| !our_names.contains(n)).collect();
    let extra: Vec<_> = our_names.iter().filter(|n| !their_names.contains(n)).collect();
    assert!(missing.is_empty() && extra.is_empty(), "{run}: not declared {missing:?}; not official {extra:?}");
    for (a, b) in ours.iter().zip(&theirs) {
        assert_eq!(a, b, "{run}");
    }
    assert_eq!(count(&ours), params, "{run}: parameters");
}

#[test]
fn srt_keys_match_official() {
    check("srt_MDBN_32", 41_037_615);
}

#[test]
fn rpsrt_k4_keys_match_official() {
    check("rpsrt_MDBN_4_32", 41_328_245);
}

#[test]
fn osrt_keys_match_official() {
    check("osrt_MDBN_64", 94_917_423);
}

#[test]
fn rposrt_k8_keys_match_official() {
    check("rposrt_MDBN_8_64", 95_213_144);
}

/// Trained parameters of the official DeFiNe runs (the key lists written by tools/data/make_golden.py from the
/// official modules; official-models.md: 30.8 M and 31.0 M).
const DEFINE_PARAMETERS: usize = 30_759_058;
const RPDEFINE_PARAMETERS: usize = 31_011_690;

#[test]
fn define_keys_match_official() {
    check("define_32_stereo_acc", DEFINE_PARAMETERS);
}

#[test]
fn rpdefine_k16_keys_match_official() {
    check("rpdefine_16_32_stereo_acc", RPDEFINE_PARAMETERS);
}

#[test]
fn official_define_dimensions() {
    for (decoder, k, heads) in [("define_32_stereo_acc", 1, (3, 1)), ("rpdefine_16_32_stereo_acc", 16, (128, 128))] {
        let config = ModelConfig::from_value("official", official::config(decoder)).unwrap();
        assert_eq!((config.base(), config.patch_size()), ("define", k), "{decoder}");
        let Family::Define(c) = &config.family else { panic!("{decoder}: not a DeFiNe config") };
        let e = &c.encoder;
        assert_eq!((e.token_dim(), c.decoder.rays.width()), (1146, 186), "{decoder}");
        assert_eq!((e.num_latents, e.latent_dim, e.heads, e.num_att_blocks), (2048, 512, 8, 8), "{decoder}");
        assert_eq!(c.head_dims(), heads, "{decoder}");
        assert!(config.has_depth());
        if let Some(rp) = &c.ray_patch {
            assert_eq!((rp.upsample, rp.conv_features, rp.batch_norm), (4, 128, true));
        }
    }
}

#[test]
fn official_dimensions() {
    let config = ModelConfig::from_value("official", official::config("rpsrt_MDBN_4_32")).unwrap();
    assert_eq!(config.patch_size(), 4);
    let c = config.srt().unwrap();
    assert_eq!(c.query_dim(), 180);
    assert_eq!(c.encoder.input_dim(), 183);
    assert_eq!(
        (c.decoder.ray_predictor.heads, c.decoder.ray_predictor.dim_head, c.decoder.ray_predictor.ff_hidden),
        (12, 64, 1536)
    );
    assert_eq!((c.encoder.heads, c.encoder.dim_head, c.encoder.ff_hidden), (12, 64, 1536));
    assert_eq!(c.decoder.out_dims, 128);
}

#[test]
fn official_osrt_dimensions() {
    for (decoder, k, out_dims) in [("osrt_MDBN_64", 1, 3), ("rposrt_MDBN_8_64", 8, 128)] {
        let config = ModelConfig::from_value("official", official::config(decoder)).unwrap();
        assert_eq!((config.base(), config.patch_size()), ("osrt", k), "{decoder}");
        let Family::Osrt(c) = &config.family else { panic!("{decoder}: not an OSRT config") };
        assert_eq!(c.query_dim(), 180);
        assert_eq!(c.encoder.input_dim(), 183);
        let s = &c.slot_attention;
        assert_eq!((s.num_slots, s.slot_dim, s.hidden, s.iters), (5, 1536, 3072, 1), "{decoder}");
        let (d, a) = (&c.decoder, &c.decoder.allocation);
        assert_eq!((a.heads, a.dim_head, a.ff_hidden, a.kv_dim), (12, 128, 3072, 1536), "{decoder}");
        assert_eq!((a.num_att_blocks, a.input_mlp_hidden, d.att_dim, d.render_hidden), (2, 360, 1536, 1536));
        assert!(!d.layer_norm);
        assert_eq!(d.out_dims, out_dims, "{decoder}: the official OSRT class overrides decoder_kwargs.out_dims");
        assert_eq!(c.image_channels(), 3, "{decoder}");
        if let Some(rp) = &c.ray_patch {
            assert_eq!((rp.upsample, rp.conv_features, rp.out_dims, rp.batch_norm), (3, 128, 3, true));
        }
    }
}

#[test]
fn bad_configs_say_what_is_wrong() {
    let mut cfg = official::config("rpsrt_MDBN_4_32");
    cfg["base"] = json!("nerf");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("m.safetensors") && err.contains("nerf") && err.contains("not supported"), "{err}");

    // An SRT config read as OSRT: the SRT decoder's 768-wide latent is not the 1536-wide slots.
    let mut cfg = official::config("rpsrt_MDBN_4_32");
    cfg["base"] = json!("osrt");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("m.safetensors") && err.contains("latent_dim") && err.contains("slot_dim"), "{err}");

    let mut cfg = official::config("osrt_MDBN_64");
    cfg["decoder"] = json!("slotmixer");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("`decoder`") && err.contains("slotmixer"), "{err}");

    let mut cfg = official::config("osrt_MDBN_64");
    cfg["encoder_kwargs"]["num_slots"] = json!(0);
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("num_slots"), "{err}");

    let mut cfg = official::config("rpsrt_MDBN_4_32");
    cfg["rp_kwargs"]["upsample"] = json!("two");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("rp_kwargs.upsample"), "{err}");

    let mut cfg = official::config("srt_MDBN_32");
    cfg["decoder_kwargs"]["latent_dim"] = json!(512);
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("latent_dim"), "{err}");
}
