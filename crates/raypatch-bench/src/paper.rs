//! The paper's figures (Ray-Patch, 3DV 2024: Table 1 on MSN-Easy, SRT and OSRT rows, and Table 3 on ScanNet,
//! DeFiNe rows, measured on an NVIDIA V100, and the attention-memory example of Section 5) beside ours where
//! they apply, and their section of `tables.md`.
//! Reads the records of [`crate::report`] (which does not depend on this module).

use serde::{Deserialize, Serialize};

use crate::flops::attention_score_bytes;
use crate::report::tables::{bytes, table};
use crate::report::Record;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Comparison {
    pub what: String,
    pub paper: String,
    pub ours: String,
}

/// Which official model a row of the paper's tables is: SRT / RP-SRT (the sweep's `official` records),
/// OSRT / RP-OSRT (`official-osrt`) or DeFiNe / RP-DeFiNe (`official-define`).
#[derive(Clone, Copy, PartialEq)]
enum PaperModel {
    Srt,
    Osrt,
    Define,
}

/// A row of Table 1: the model, target size, k, rendering speed in fps on a V100, "Giga FLOPs".
struct PaperRow(PaperModel, (usize, usize), usize, f64, f64);

/// Table 1 (MSN-Easy) and Table 3 (ScanNet, DeFiNe: two 128x192 input views, 480x640 targets).
const TABLES: [PaperRow; 10] = [
    PaperRow(PaperModel::Srt, (60, 80), 1, 117.0, 48.2),
    PaperRow(PaperModel::Srt, (60, 80), 2, 288.0, 15.8),
    PaperRow(PaperModel::Srt, (60, 80), 4, 341.0, 7.3),
    PaperRow(PaperModel::Srt, (120, 160), 1, 30.0, 192.1),
    PaperRow(PaperModel::Srt, (120, 160), 4, 275.0, 28.5),
    PaperRow(PaperModel::Srt, (120, 160), 8, 305.0, 19.7),
    PaperRow(PaperModel::Osrt, (120, 160), 1, 21.0, 278.6),
    PaperRow(PaperModel::Osrt, (120, 160), 8, 278.0, 24.7),
    PaperRow(PaperModel::Define, (480, 640), 1, 7.0, 801.0),
    PaperRow(PaperModel::Define, (480, 640), 16, 208.0, 81.0),
];

fn official(records: &[Record], paper_model: PaperModel, size: (usize, usize), k: usize) -> Option<&Record> {
    let size = format!("{}x{}", size.0, size.1);
    let model = match paper_model {
        PaperModel::Srt => "official",
        PaperModel::Osrt => "official-osrt",
        PaperModel::Define => "official-define",
    };
    records.iter().find(|r| {
        r.group == "sweep"
            && r.model == model
            && r.k == k
            && r.target_size == size
            && r.precision == "f32"
            && r.fps.is_some()
    })
}

fn name(paper_model: PaperModel, k: usize) -> String {
    let base = match paper_model {
        PaperModel::Srt => "SRT",
        PaperModel::Osrt => "OSRT",
        PaperModel::Define => "DeFiNe",
    };
    if k == 1 {
        base.into()
    } else {
        format!("RP-{base} k={k}")
    }
}

/// Two decimals, three below 0.1 fps (OSRT's full-size renders take over a minute on a CPU).
fn fps_text(fps: f64) -> String {
    if fps < 0.1 {
        format!("{fps:.3}")
    } else {
        format!("{fps:.2}")
    }
}

pub fn compare(records: &[Record]) -> Vec<Comparison> {
    let mut rows = Vec::new();
    let adapter = records.iter().find_map(|r| r.env.as_ref()).map_or(String::new(), |e| e.adapter.clone());
    for &PaperRow(paper_model, size, k, fps, gflops) in &TABLES {
        let ours = official(records, paper_model, size, k);
        let name = |k| name(paper_model, k);
        rows.push(Comparison {
            what: format!("{} {}x{}: rendering speed", name(k), size.0, size.1),
            paper: format!("{fps:.0} fps (V100)"),
            ours: ours
                .and_then(|r| r.fps)
                .map_or("not measured".into(), |f| format!("{} fps ({adapter})", fps_text(f))),
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
            let per_pixel = TABLES.iter().find(|row| row.0 == paper_model && row.1 == size && row.2 == 1);
            let srt = per_pixel.map_or(1.0, |row| row.3);
            let base = official(records, paper_model, size, 1).and_then(|r| r.fps);
            let ours = match (base, ours.and_then(|r| r.fps)) {
                (Some(s), Some(r)) => format!("{:.1}x", r / s),
                _ => "not measured".into(),
            };
            rows.push(Comparison {
                what: format!("{} {}x{}: speed-up over {}", name(k), size.0, size.1, name(1)),
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
    for (paper_model, model) in [(PaperModel::Srt, "official"), (PaperModel::Define, "official-define")] {
        for k in [1, 16] {
            let size = format!("{}x{}", 960, 1280);
            let Some(r) =
                records.iter().find(|r| r.model == model && r.k == k && r.target_size == size && r.group == "sweep")
            else {
                continue;
            };
            rows.push(Comparison {
                what: format!(
                    "official {} 960x1280: materialised scores vs the engine's planned peak",
                    name(paper_model, k)
                ),
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
