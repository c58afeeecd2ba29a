//! Work per encode and per rendered frame, counted from the model's shapes: the multiply-accumulates (MACs)
//! of every linear layer, convolution and attention product that `srt.rs` records. Elementwise work (norms,
//! activations, softmax exponentials, encodings, resizes) is linear in the activations and left out, as
//! FLOP counters usually do. One MAC is two FLOPs.

use raypatch_model::ModelConfig;

/// Latent tokens of `n` input views of `h`×`w` (each conv block halves the size, rounding up).
pub fn tokens(cfg: &ModelConfig, n: usize, h: usize, w: usize) -> usize {
    let (mut h, mut w) = (h, w);
    for _ in 0..cfg.encoder.num_conv_blocks {
        (h, w) = (h.div_ceil(2), w.div_ceil(2));
    }
    n * h * w
}

/// MACs of encoding `n` views of `h`×`w`: conv blocks, per-patch linear, transformer, decoder keys/values.
pub fn encode_macs(cfg: &ModelConfig, n: usize, h: usize, w: usize) -> u64 {
    let e = &cfg.encoder;
    let mut macs = 0u64;
    let (mut h, mut w) = (h, w);
    for (cin, hidden, cout) in cfg.encoder_conv_widths() {
        macs += (n * h * w * hidden * cin * 9) as u64;
        (h, w) = (h.div_ceil(2), w.div_ceil(2));
        macs += (n * h * w * cout * hidden * 9) as u64;
    }
    let t = (n * h * w) as u64;
    let conv_out = cfg.encoder_conv_widths().last().map_or(0, |c| c.2) as u64;
    let (dim, inner, ff) = (e.token_dim as u64, (e.heads * e.dim_head) as u64, e.ff_hidden as u64);
    macs += t * dim * conv_out;
    let per_layer = t * (dim * 3 * inner + inner * dim + 2 * dim * ff) + 2 * t * t * inner;
    macs += e.num_att_blocks as u64 * per_layer;
    let d = &cfg.decoder;
    macs += d.num_att_blocks as u64 * t * dim * 2 * (d.heads * d.dim_head) as u64;
    macs
}

/// MACs of rendering `views` target views of `height`×`width` against `tokens` latent tokens: the decoder
/// on every query (one per pixel, or per k×k patch) and the Ray-Patch conv decoder.
pub fn render_macs(cfg: &ModelConfig, views: usize, height: usize, width: usize, tokens: usize) -> u64 {
    let d = &cfg.decoder;
    let k = cfg.patch_size();
    let (ph, pw) = (height / k, width / k);
    let queries = (views * ph * pw) as u64;
    let (q, inner, t) = (cfg.query_dim() as u64, (d.heads * d.dim_head) as u64, tokens as u64);
    let (mlp_in, mlp_out) = (d.input_mlp_hidden as u64, d.out_mlp_hidden as u64);
    let per_layer = q * inner + 2 * t * inner + inner * q + 2 * q * d.ff_hidden as u64;
    let per_query = 2 * q * mlp_in
        + d.num_att_blocks as u64 * per_layer
        + q * mlp_out
        + 3 * mlp_out * mlp_out
        + mlp_out * d.out_dims as u64;
    let mut macs = queries * per_query;
    if let Some(rp) = &cfg.ray_patch {
        let channels = rp.out_dims as u64;
        let mut pixels = queries;
        macs += pixels * channels * rp.conv_features as u64 * 9;
        for i in 0..rp.upsample {
            let (cin, cout) = ((rp.conv_features >> i) as u64, (rp.conv_features >> (i + 1)) as u64);
            pixels *= 4;
            macs += pixels * (cout * cin + channels * cout) * 9;
        }
    }
    macs
}

/// Bytes a decoder that materialised its softmax would hold at once for one frame: the `queries × tokens`
/// score matrix per head in f32, the quantity of the paper's Figure 2a (the engine's online softmax never
/// stores it).
pub fn attention_score_bytes(queries: usize, tokens: usize, heads: usize) -> u64 {
    (queries * tokens * heads * 4) as u64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{official_rpsrt_config, official_srt_config};

    /// Hand counts for the official SRT decoder (per query: input_mlp 2·180·360, per layer
    /// 180·768 + 2·300·768 + 768·180 + 2·180·1536, out_mlp 180·1536 + 3·1536² + 1536·3).
    #[test]
    fn official_decoder_per_query() {
        let cfg = ModelConfig::from_value("srt", official_srt_config()).unwrap();
        let per_query: u64 = 2 * 180 * 360
            + 2 * (180 * 768 + 2 * 300 * 768 + 768 * 180 + 2 * 180 * 1536)
            + 180 * 1536
            + 3 * 1536 * 1536
            + 1536 * 3;
        assert_eq!(render_macs(&cfg, 1, 60, 80, 300), 4800 * per_query);
        assert_eq!(tokens(&cfg, 1, 120, 160), 300);
        let rp = ModelConfig::from_value("rpsrt", official_rpsrt_config(2)).unwrap();
        let per_patch = per_query - 1536 * 3 + 1536 * 128;
        let convs: u64 = 1200 * 3 * 128 * 9 + 4800 * (64 * 128 + 3 * 64) * 9;
        assert_eq!(render_macs(&rp, 1, 60, 80, 300), 1200 * per_patch + convs);
    }

    /// The paper's example: a 960×1280 DeFiNe decode with 2048 latents and 8 heads is 75 GiB of scores,
    /// and ~0.3 GiB with k = 16.
    #[test]
    fn paper_attention_memory_example() {
        let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
        assert!((gib(attention_score_bytes(960 * 1280, 2048, 8)) - 75.0).abs() < 0.01);
        assert!((gib(attention_score_bytes(960 * 1280 / 256, 2048, 8)) - 0.293).abs() < 0.001);
    }
}
