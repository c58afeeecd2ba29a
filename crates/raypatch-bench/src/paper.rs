//! The paper's figures (Ray-Patch, 3DV 2024: Table 1 on MSN-Easy, measured on an NVIDIA V100, and the
//! attention-memory example of Section 5) beside ours where they apply, and their section of `tables.md`.
//! Reads the records of [`crate::report`] (which does not depend on this module).

use serde::{Deserialize, Serialize};

use crate::flops::attention_score_bytes;
use crate::report::{bytes, table, Record};

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Comparison {
    pub what: String,
    pub paper: String,
    pub ours: String,
}

/// Table 1, MSN-Easy: (target size, k, rendering speed in fps on a V100, "Giga FLOPs").
const TABLE_1: [((usize, usize), usize, f64, f64); 6] = [
    ((60, 80), 1, 117.0, 48.2),
    ((60, 80), 2, 288.0, 15.8),
    ((60, 80), 4, 341.0, 7.3),
    ((120, 160), 1, 30.0, 192.1),
    ((120, 160), 4, 275.0, 28.5),
    ((120, 160), 8, 305.0, 19.7),
];

fn official(records: &[Record], size: (usize, usize), k: usize) -> Option<&Record> {
    let size = format!("{}x{}", size.0, size.1);
    records.iter().find(|r| {
        r.group == "sweep"
            && r.model == "official"
            && r.k == k
            && r.target_size == size
            && r.precision == "f32"
            && r.fps.is_some()
    })
}

fn name(k: usize) -> String {
    if k == 1 {
        "SRT".into()
    } else {
        format!("RP-SRT k={k}")
    }
}

pub fn compare(records: &[Record]) -> Vec<Comparison> {
    let mut rows = Vec::new();
    let adapter = records.iter().find_map(|r| r.env.as_ref()).map_or(String::new(), |e| e.adapter.clone());
    for &(size, k, fps, gflops) in &TABLE_1 {
        let ours = official(records, size, k);
        rows.push(Comparison {
            what: format!("{} {}x{}: rendering speed", name(k), size.0, size.1),
            paper: format!("{fps:.0} fps (V100)"),
            ours: ours.and_then(|r| r.fps).map_or("not measured".into(), |f| format!("{f:.2} fps ({adapter})")),
        });
        rows.push(Comparison {
            what: format!("{} {}x{}: work per frame", name(k), size.0, size.1),
            paper: format!("{gflops} \"Giga FLOPs\""),
            // The paper's counts match multiply-accumulates (one MAC as one "FLOP"), as fvcore-style counters give.
            ours: ours.map_or("not measured".into(), |r| {
                let (render, encode) = (r.render_gflop / 2.0, r.encode_gflop / 2.0);
                format!("{:.1} GMAC (render {render:.1} + encode {encode:.1})", render + encode)
            }),
        });
        if k > 1 {
            let srt = TABLE_1.iter().find(|row| row.0 == size && row.1 == 1).map_or(1.0, |row| row.2);
            let ours = match (official(records, size, 1).and_then(|r| r.fps), ours.and_then(|r| r.fps)) {
                (Some(s), Some(r)) => format!("{:.1}x", r / s),
                _ => "not measured".into(),
            };
            rows.push(Comparison {
                what: format!("{} {}x{}: speed-up over SRT", name(k), size.0, size.1),
                paper: format!("{:.1}x", fps / srt),
                ours,
            });
        }
    }
    // Section 5: a DeFiNe decode of one 960×1280 image against 2048 latents (8 heads) materialises its
    // softmax: 75 GB; with k = 16, 0.3 GB. The same formula for the official SRT (300 tokens, 12 heads) and
    // the memory the engine plans (its online softmax stores no score matrix; queries run in chunks).
    rows.push(Comparison {
        what: "attention memory, 960x1280 DeFiNe decode (2048 latents, 8 heads), SRT vs RP k=16".into(),
        paper: "75 GB vs 0.3 GB".into(),
        ours: format!(
            "{} vs {} by the same formula",
            bytes(attention_score_bytes(960 * 1280, 2048, 8)),
            bytes(attention_score_bytes(960 * 1280 / 256, 2048, 8))
        ),
    });
    for k in [1, 16] {
        let size = format!("{}x{}", 960, 1280);
        if let Some(r) =
            records.iter().find(|r| r.model == "official" && r.k == k && r.target_size == size && r.group == "sweep")
        {
            rows.push(Comparison {
                what: format!("official {} 960x1280: materialised scores vs the engine's planned peak", name(k)),
                paper: "-".into(),
                ours: format!(
                    "{} vs {}",
                    bytes(r.attention_scores_bytes),
                    r.render_peak_bytes.map_or("-".into(), bytes)
                ),
            });
        }
    }
    rows
}

/// The comparison as the last section of `tables.md`.
pub fn markdown(comparison: &[Comparison]) -> String {
    let mut out = "### The paper's figures beside ours\n\n".to_string();
    table(
        &mut out,
        &["", "paper", "ours"],
        comparison.iter().map(|c| vec![c.what.clone(), c.paper.clone(), c.ours.clone()]).collect(),
    );
    out
}
