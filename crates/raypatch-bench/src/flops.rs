//! Work per encode and per rendered frame. The harness takes the multiply-adds from the engine, which counts
//! them from the ops a plan records ([`raypatch_engine::RenderStats::multiply_adds`],
//! [`raypatch_engine::EncodedScene::encode_multiply_adds`], and without building a plan
//! [`raypatch_engine::Model::encode_multiply_adds`] and [`raypatch_engine::EncodedScene::render_multiply_adds`]):
//! every linear layer, convolution and attention product. Elementwise work (norms, activations, softmax
//! exponentials, encodings, resizes) is linear in the activations and counted as none, as FLOP counters
//! usually do. One multiply-add is two FLOPs. The tests below check the counts against a hand count.
//!
//! What stays here is a quantity of the paper, not of our work: the bytes a materialised softmax would take.

/// Bytes a decoder that materialised its softmax would hold at once for one frame: the `queries × tokens`
/// score matrix per head in f32, the quantity of the paper's Figure 2a (the engine's online softmax never
/// stores it).
pub fn attention_score_bytes(queries: usize, tokens: usize, heads: usize) -> u64 {
    (queries * tokens * heads * 4) as u64
}

/// Two FLOPs per multiply-add, in GFLOP.
pub fn gflop(multiply_adds: u64) -> f64 {
    2.0 * multiply_adds as f64 / 1e9
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use raypatch_engine::{Gpu, GpuOptions, Model, Outputs};

    use super::*;
    use crate::synthetic::{random_model, small_config, synthetic_scene, CameraRig};

    /// The paper's example: a 960×1280 DeFiNe decode with 2048 latents and 8 heads is 75 GiB of scores,
    /// and ~0.3 GiB with k = 16.
    #[test]
    fn paper_attention_memory_example() {
        let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
        assert!((gib(attention_score_bytes(960 * 1280, 2048, 8)) - 75.0).abs() < 0.01);
        assert!((gib(attention_score_bytes(960 * 1280 / 256, 2048, 8)) - 0.293).abs() < 0.001);
    }

    /// The multiply-adds the engine counts from its ops, for the small SRT and RP-SRT k=2 models at width 8
    /// (one 16×16 input view, one 8×8 target view), against a hand count of their layers. Built (and
    /// rendered) on the default adapter: a GPU, or lavapipe.
    #[test]
    fn op_counts_equal_a_hand_count() {
        // small_config(k, 8): encoder 3 conv blocks (input 3 + 90 + 90 = 183 channels, hidden 2 → 4, 4 → 8,
        // 8 → 16), tokens 8 wide, 2 layers of 4 heads × 2, feed-forward 16; decoder queries 90 + 90 = 180
        // wide, input MLP 24, 2 layers of 4 heads × 2 on keys/values 8 wide, feed-forward 16, out MLP 48.
        let (q, inner, ff, mlp_in, mlp_out, dim) = (180u64, 8u64, 16u64, 24u64, 48u64, 8u64);
        // 16×16 → 8×8 → 4×4 → 2×2: 4 tokens.
        let t = 4u64;
        // Each conv block: a conv at its input size, then a stride-2 conv to half the size.
        let conv_blocks =
            (256 * 2 * 183 + 64 * 4 * 2) * 9 + (64 * 4 * 4 + 16 * 8 * 4) * 9 + (16 * 8 * 8 + 4 * 16 * 8) * 9;
        let per_patch_linear = t * 16 * dim;
        // Per layer: to_qkv, to_out, feed-forward, q·kᵀ and ·v.
        let transformer = 2 * (t * (dim * 3 * inner + inner * dim + dim * ff + ff * dim) + 2 * t * t * inner);
        // The decoder's keys and values (to_kv per layer), once per scene.
        let keys_values = 2 * t * dim * 2 * inner;
        let encode = conv_blocks + per_patch_linear + transformer + keys_values;
        // Per query: input MLP, 2 cross-attention layers (to_q, q·kᵀ and ·v, to_out, feed-forward), out MLP
        // (four hidden layers, then the output).
        let per_query = |out_dims: u64| {
            (q * mlp_in + mlp_in * q)
                + 2 * (q * inner + 2 * t * inner + inner * q + q * ff + ff * q)
                + (q * mlp_out + 3 * mlp_out * mlp_out + mlp_out * out_dims)
        };
        // SRT: one query per pixel of 8×8.
        let srt = 64 * per_query(3);
        // RP-SRT k=2: 4×4 queries of 16 features; conv_0 (16 → 3) on the patch grid, then one 2× block: the
        // feature conv (16 → 8) on the upsampled 8×8 grid and its rgb conv (8 → 3).
        let rpsrt = 16 * per_query(16) + 16 * 16 * 3 * 9 + 64 * (16 * 8 + 8 * 3) * 9;

        let gpu = Arc::new(Gpu::new(&GpuOptions::default()).expect("no GPU adapter: install Mesa lavapipe"));
        let (inputs, targets) = synthetic_scene(3, 1, (16, 16), 1, (8, 8), &CameraRig::default()).unwrap();
        for (k, want_render) in [(1, srt), (2, rpsrt)] {
            let (loaded, _) = random_model(&small_config(k, 8), 7, "small").unwrap();
            let model = Model::from_loaded(gpu.clone(), &loaded).unwrap();
            assert_eq!(model.encode_multiply_adds(1, 16, 16), encode, "k={k}: predicted encode");
            let encoded = model.encode(&inputs).unwrap();
            assert_eq!(encoded.latent.rows as u64, t);
            assert_eq!(encoded.encode_multiply_adds, encode, "k={k}: encode plan");
            assert_eq!(encoded.render_multiply_adds(&targets, Outputs::default()).unwrap(), want_render, "k={k}");
            encoded.render(&targets, Outputs::default()).unwrap();
            let stats = encoded.render_stats(&targets, Outputs::default()).unwrap();
            assert_eq!(stats.multiply_adds, want_render, "k={k}: render plan");
        }
    }
}
