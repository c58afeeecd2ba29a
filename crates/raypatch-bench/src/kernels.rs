//! Where the GPU time of a render goes: per-op timestamps summed per op of the model (layer indices and
//! query chunks folded together) and per kernel.

use std::collections::HashMap;

use raypatch_engine::gpu::GpuTimes;

use crate::report::KernelTime;

/// An op label with query-chunk ranges (`[0..5440]`) removed and layer, block and skip indices folded to `*`:
/// `decoder_att.ray_predictor.transformer.layers.1[0..64].0.fn.to_q` → `…transformer.layers.*.0.fn.to_q`.
pub fn fold_label(label: &str) -> String {
    let mut unchunked = String::with_capacity(label.len());
    let mut depth = 0;
    for c in label.chars() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            _ if depth == 0 => unchunked.push(c),
            _ => {}
        }
    }
    let parts: Vec<&str> = unchunked.split('.').collect();
    let folded: Vec<&str> = parts
        .iter()
        .enumerate()
        .map(|(i, part)| {
            let indexed = i > 0 && matches!(parts[i - 1], "layers" | "conv_blocks" | "skip");
            if indexed && part.chars().all(|c| c.is_ascii_digit()) {
                "*"
            } else {
                part
            }
        })
        .collect();
    folded.join(".")
}

/// Per folded op, then per kernel (op `*`), sorted by time, for the configuration `config`.
pub fn fold(config: &str, times: &GpuTimes) -> Vec<KernelTime> {
    let total: f64 = times.ops.iter().map(|o| o.time.as_secs_f64()).sum::<f64>().max(1e-12);
    let mut by_op: HashMap<(String, String), (usize, f64)> = HashMap::new();
    let mut by_kernel: HashMap<String, (usize, f64)> = HashMap::new();
    for op in &times.ops {
        let t = op.time.as_secs_f64();
        let entry = by_op.entry((fold_label(&op.label), op.kernel.clone())).or_default();
        *entry = (entry.0 + 1, entry.1 + t);
        let entry = by_kernel.entry(op.kernel.clone()).or_default();
        *entry = (entry.0 + 1, entry.1 + t);
    }
    let row = |op: String, kernel: String, (dispatches, seconds): (usize, f64)| KernelTime {
        config: config.to_string(),
        op,
        kernel,
        dispatches,
        ms: seconds * 1e3,
        share: seconds / total,
    };
    let mut kernels: Vec<KernelTime> = by_kernel.into_iter().map(|(k, v)| row("*".into(), k, v)).collect();
    let mut ops: Vec<KernelTime> = by_op.into_iter().map(|((o, k), v)| row(o, k, v)).collect();
    kernels.sort_by(|a, b| b.ms.total_cmp(&a.ms));
    ops.sort_by(|a, b| b.ms.total_cmp(&a.ms));
    kernels.extend(ops);
    kernels
}

#[cfg(test)]
mod tests {
    use super::fold_label;

    #[test]
    fn labels_fold_layers_and_chunks() {
        assert_eq!(
            fold_label("decoder_att.ray_predictor.transformer.layers.1[0..5440].0.fn.to_q"),
            "decoder_att.ray_predictor.transformer.layers.*.0.fn.to_q"
        );
        assert_eq!(fold_label("decoder_att.out_mlp.2[64..128]"), "decoder_att.out_mlp.2");
        assert_eq!(fold_label("decoder_rp.conv_decoder.conv_blocks.2.0"), "decoder_rp.conv_decoder.conv_blocks.*.0");
        assert_eq!(fold_label("encoder.transformer.layers.4.1.fn.net.3"), "encoder.transformer.layers.*.1.fn.net.3");
    }
}
