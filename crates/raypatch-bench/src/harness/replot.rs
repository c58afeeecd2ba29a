//! `raypatch-bench --replot`: tables and plots again from results.json files, merged where several are given.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::Results;
use crate::report::{self, Record};
use crate::{paper, plots};

/// Writes tables.md and the plots again from results.json files (e.g. after changing how they are drawn).
/// With several files, later files' records replace earlier ones of the same configuration (model, decoder,
/// k, precision, target views and size, variant) and the others are kept: a partial run (`--only`) updates a full one.
/// The merged results.json, results.csv and kernels.csv are written into `out` too.
pub fn replot(files: &[PathBuf], out: &Path) -> Result<()> {
    let mut merged: Option<Results> = None;
    for file in files {
        let text = std::fs::read_to_string(file).with_context(|| format!("{}: cannot read", file.display()))?;
        let next: Results = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a raypatch-bench results.json", file.display()))?;
        merged = Some(match merged {
            None => next,
            Some(mut all) => {
                let key = |r: &Record| {
                    (
                        r.model.clone(),
                        r.decoder.clone(),
                        r.k,
                        r.precision.clone(),
                        r.target_views,
                        r.target_size.clone(),
                        r.variant.clone(),
                    )
                };
                for record in next.results {
                    match all.results.iter_mut().find(|r| key(r) == key(&record)) {
                        Some(old) => *old = record,
                        None => all.results.push(record),
                    }
                }
                let configs: Vec<String> = next.kernels.iter().map(|k| k.config.clone()).collect();
                all.kernels.retain(|k| !configs.contains(&k.config));
                all.kernels.extend(next.kernels);
                all.command = format!("{}\n{}", all.command, next.command);
                all.paper_comparison = paper::compare(&all.results);
                all
            }
        });
    }
    let results = merged.context("no results.json to replot")?;
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create the output folder", out.display()))?;
    if files.len() > 1 {
        let json = serde_json::to_string_pretty(&results)?;
        report::write_file(&out.join("results.json"), json.as_bytes())?;
        report::write_csv(&out.join("results.csv"), &results.results)?;
        report::write_csv(&out.join("kernels.csv"), &results.kernels)?;
    }
    let tables = report::markdown(&results.results, &results.kernels, &results.pytorch)
        + &paper::markdown(&results.paper_comparison);
    report::write_file(&out.join("tables.md"), tables.as_bytes())?;
    plots::draw_all(&results.results, out)?;
    println!("wrote tables.md and {} in {}", plots::FILES.join(", "), out.display());
    Ok(())
}
