//! The SRT module tree built from the official run configs fetches exactly the official state_dict names
//! and shapes (`models::expected_tensors`, no file, no GPU).

use raypatch_engine::models::expected_tensors;
use raypatch_model::ModelConfig;
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

fn check(decoder: &str, file: &str) {
    let config = ModelConfig::from_value("official", official(decoder)).unwrap();
    let mut ours = expected_tensors(&config).unwrap();
    let mut theirs = official_keys(file);
    ours.sort();
    theirs.sort();
    assert_eq!(ours.len(), theirs.len(), "tensor count for {file}");
    for (a, b) in ours.iter().zip(&theirs) {
        assert_eq!(a, b, "{file}");
    }
}

#[test]
fn srt_keys_match_official() {
    check("lightfield", "official-keys-srt_MDBN_32.txt");
}

#[test]
fn rpsrt_k4_keys_match_official() {
    check("featurefield", "official-keys-rpsrt_MDBN_4_32.txt");
}

#[test]
fn official_dimensions() {
    let config = ModelConfig::from_value("official", official("featurefield")).unwrap();
    assert_eq!(config.patch_size(), 4);
    let c = config.srt().unwrap();
    assert_eq!(c.query_dim(), 180);
    assert_eq!(c.encoder.input_dim(), 183);
    assert_eq!((c.decoder.heads, c.decoder.dim_head, c.decoder.ff_hidden), (12, 64, 1536));
    assert_eq!((c.encoder.heads, c.encoder.dim_head, c.encoder.ff_hidden), (12, 64, 1536));
    assert_eq!(c.decoder.out_dims, 128);
}

#[test]
fn bad_configs_say_what_is_wrong() {
    let mut cfg = official("featurefield");
    cfg["base"] = json!("osrt");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("m.safetensors") && err.contains("osrt"), "{err}");

    let mut cfg = official("featurefield");
    cfg["rp_kwargs"]["upsample"] = json!("two");
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("rp_kwargs.upsample"), "{err}");

    let mut cfg = official("lightfield");
    cfg["decoder_kwargs"]["latent_dim"] = json!(512);
    let err = ModelConfig::from_value("m.safetensors", cfg).unwrap_err().to_string();
    assert!(err.contains("latent_dim"), "{err}");
}
