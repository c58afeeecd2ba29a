//! The module trees built from the official run configs (SRT, RP-SRT, OSRT, RP-OSRT, DeFiNe, RP-DeFiNe) fetch exactly the
//! official state_dict names and shapes, and hold the official parameter counts (`models::expected_tensors`,
//! no file, no GPU).

use raypatch_engine::models::expected_tensors;
use raypatch_model::{Family, ModelConfig};
use serde_json::json;

/// The model sections of RayPatchQuerying's runs/msn_easy/{srt_MDBN_32,rpsrt_MDBN_4_32}/config.yaml.
fn official(decoder: &str) -> serde_json::Value {
    let mut cfg = json!({
        "base": "srt",
        "encoder_kwargs": {"pos_start_octave": -5, "num_att_blocks": 5, "num_conv_blocks": 3, "norm": "Batch"},
        "decoder": decoder,
        "decoder_kwargs": {"pos_octaves": 15, "ray_octaves": 15, "pos_start_octave": -5, "pos_end_octave": null,
                           "ray_start_octave": 0, "ray_end_octave": null, "latent_dim": 768, "mode": "efficient", "out_dims": 3},
        "lr_config": "linear", "gamma": null, "lr": 0.0001, "decay_it": 500000, "lr_warmup": 2500
    });
    if decoder == "featurefield" {
        cfg["rp_kwargs"] = json!({"upsample": 2, "h_in": 30, "w_in": 40, "conv_features": 128, "norm": "Batch"});
        cfg["decoder_kwargs"].as_object_mut().unwrap().remove("out_dims");
    }
    cfg
}

/// The model sections of RayPatchQuerying's runs/msn_easy/{osrt_MDBN_64,rposrt_MDBN_8_64}/config.yaml. They
/// set no decoder_kwargs.out_dims: the official OSRT class overrides it (3 for lightfield, the Ray-Patch
/// conv_features, by default 128, for featurefield).
fn official_osrt(decoder: &str) -> serde_json::Value {
    let mut cfg = json!({
        "base": "osrt",
        "encoder_kwargs": {"max_pooling": false, "pos_start_octave": -5, "num_conv_blocks": 3, "num_att_blocks": 5,
                           "num_slots": 5, "norm": "Batch", "latent_dim": 1536},
        "decoder": decoder,
        "decoder_kwargs": {"pos_start_octave": -5},
        "lr_config": "linear", "lr": 0.0001, "decay_it": 4000000, "lr_warmup": 2500, "gamma": 0.16
    });
    if decoder == "featurefield" {
        cfg["rp_kwargs"] = json!({"out_dims": 3, "norm": "Batch", "upsample": 3, "h_in": 15, "w_in": 20,
                                  "h_out": 120, "w_out": 160});
    }
    cfg
}

/// The model sections of RayPatchQuerying's runs/scannet/{define_32_stereo_acc,rpdefine_16_32_stereo_acc}/
/// config.yaml.
fn official_define(decoder: &str) -> serde_json::Value {
    let mut cfg = json!({
        "base": "define",
        "encoder_kwargs": {"pos_start_octave": 1, "num_att_blocks": 8},
        "decoder": decoder,
        "decoder_kwargs": {"pos_start_octave": 1},
        "lr_config": "step", "lr": 0.0002, "lr_warmup": 2500
    });
    if decoder == "featurefield" {
        cfg["rp_kwargs"] = json!({"h_in": 30, "w_in": 40, "upsample": 4, "norm": "Batch"});
    }
    cfg
}

/// Reads a key list from official-state-dict-keys.txt: `name [d0, d1, ...]` per line.
fn official_keys(file: &str) -> Vec<(String, Vec<usize>)> {
    let text = std::fs::read_to_string(format!("{}/tests/data/{file}", env!("CARGO_MANIFEST_DIR"))).unwrap();
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let (name, shape) = l.split_once(' ').unwrap();
            let dims = shape.trim_matches(|c| c == '[' || c == ']');
            let dims = dims.split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse().unwrap()).collect();
            (name.to_string(), dims)
        })
        .filter(|(name, _)| !name.ends_with("num_batches_tracked"))
        .collect()
}

/// Checks the module tree of `config` against the official key list `file`: the same names and shapes, and
/// `params` parameters (the header of shared/reference/official-state-dict-keys.txt: `model.parameters()`,
/// BatchNorm running statistics not counted).
fn check(config: serde_json::Value, file: &str, params: usize) {
    let config = ModelConfig::from_value("official", config).unwrap();
    let mut ours = expected_tensors(&config).unwrap();
    let mut theirs = official_keys(file);
    let count = |keys: &[(String, Vec<usize>)]| {
        let trained = keys.iter().filter(|(name, _)| !name.ends_with("running_mean") && !name.ends_with("running_var"));
        trained.map(|(_, shape)| shape.iter().product::<usize>()).sum::<usize>()
    };
    assert_eq!(count(&theirs), params, "{file}: the key list does not hold the header's parameter count");
    ours.sort();
    theirs.sort();
    let names = |keys: &[(String, Vec<usize>)]| keys.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    let (our_names, their_names) = (names(&ours), names(&theirs));
    let missing: Vec<_> = their_names.iter().filter(|n| !our_names.contains(n)).collect();
    let extra: Vec<_> = our_names.iter().filter(|n| !their_names.contains(n)).collect();
    assert!(missing.is_empty() && extra.is_empty(), "{file}: not declared {missing:?}; not official {extra:?}");
    for (a, b) in ours.iter().zip(&theirs) {
        assert_eq!(a, b, "{file}");
    }
    assert_eq!(count(&ours), params, "{file}: parameters");
}

#[test]
fn srt_keys_match_official() {
    check(official("lightfield"), "official-keys-srt_MDBN_32.txt", 41_037_615);
}

#[test]
fn rpsrt_k4_keys_match_official() {
    check(official("featurefield"), "official-keys-rpsrt_MDBN_4_32.txt", 41_328_245);
}

#[test]
fn osrt_keys_match_official() {
    check(official_osrt("lightfield"), "official-keys-osrt_MDBN_64.txt", 94_917_423);
}

#[test]
fn rposrt_k8_keys_match_official() {
    check(official_osrt("featurefield"), "official-keys-rposrt_MDBN_8_64.txt", 95_213_144);
}

/// Trained parameters of the official DeFiNe runs (the key lists written by tools/make_golden.py from the
/// official modules; official-models.md: 30.8 M and 31.0 M).
const DEFINE_PARAMETERS: usize = 30_759_058;
const RPDEFINE_PARAMETERS: usize = 31_011_690;

#[test]
fn define_keys_match_official() {
    check(official_define("lightfield"), "official-keys-define_32_stereo_acc.txt", DEFINE_PARAMETERS);
}

#[test]
fn rpdefine_k16_keys_match_official() {
    check(official_define("featurefield"), "official-keys-rpdefine_16_32_stereo_acc.txt", RPDEFINE_PARAMETERS);
}

#[test]
fn official_define_dimensions() {
    for (decoder, k, heads) in [("lightfield", 1, (3, 1)), ("featurefield", 16, (128, 128))] {
        let config = ModelConfig::from_value("official", official_define(decoder)).unwrap();
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
    let config = ModelConfig::from_value("official", official("featurefield")).unwrap();
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
    for (decoder, k, out_dims) in [("lightfield", 1, 3), ("featurefield", 8, 128)] {
        let config = ModelConfig::from_value("official", official_osrt(decoder)).unwrap();
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
    let mut cfg = official("featurefield");
    cfg["base"] = json!("nerf");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("m.safetensors") && err.contains("nerf") && err.contains("not supported"), "{err}");

    // An SRT config read as OSRT: the SRT decoder's 768-wide latent is not the 1536-wide slots.
    let mut cfg = official("featurefield");
    cfg["base"] = json!("osrt");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("m.safetensors") && err.contains("latent_dim") && err.contains("slot_dim"), "{err}");

    let mut cfg = official_osrt("lightfield");
    cfg["decoder"] = json!("slotmixer");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("`decoder`") && err.contains("slotmixer"), "{err}");

    let mut cfg = official_osrt("lightfield");
    cfg["encoder_kwargs"]["num_slots"] = json!(0);
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("num_slots"), "{err}");

    let mut cfg = official("featurefield");
    cfg["rp_kwargs"]["upsample"] = json!("two");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("rp_kwargs.upsample"), "{err}");

    let mut cfg = official("lightfield");
    cfg["decoder_kwargs"]["latent_dim"] = json!(512);
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("latent_dim"), "{err}");
}
