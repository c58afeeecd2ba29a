//! `raypatch-bench --replot`: tables and plots again from results.json files, merged where several are given.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::Results;
use crate::report::{self, Record};
use crate::{paper, plots};

/// Writes tables.md and the plots again from results.json files (e.g. after changing how they are drawn).
/// With several files, later files' records replace earlier ones of the same configuration (model, decoder,
/// k, precision, kernel family, target views and size, variant) and the others are kept: a partial run (`--only`)
/// updates a full one. (A record from before kernels were recorded matches any kernel: f16-act on the tensor
/// kernels and on the others are two configurations.)
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
                for record in next.results {
                    match all.results.iter_mut().find(|r| same_configuration(r, &record)) {
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
    let tables = report::tables::markdown(&results.results, &results.kernels, &results.pytorch)
        + &paper::markdown(&results.paper_comparison);
    report::write_file(&out.join("tables.md"), tables.as_bytes())?;
    plots::draw_all(&results.results, out)?;
    println!("wrote tables.md and {} in {}", plots::FILES.join(", "), out.display());
    Ok(())
}

/// Whether two records measured the same configuration (one replaces the other when merged).
fn same_configuration(a: &Record, b: &Record) -> bool {
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
    key(a) == key(b) && (a.kernel == b.kernel || a.kernel.is_empty() || b.kernel.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f16_act_on_two_kernel_families_is_two_configurations() {
        let record = |precision: &str, kernel: &str| Record {
            model: "official".into(),
            k: 8,
            precision: precision.into(),
            kernel: kernel.into(),
            target_size: "120x160".into(),
            ..Default::default()
        };
        assert!(!same_configuration(&record("f16-act", "Coop"), &record("f16-act", "Lanes")));
        assert!(same_configuration(&record("f16-act", "Lanes"), &record("f16-act", "Lanes")));
        assert!(same_configuration(&record("f32", ""), &record("f32", "Lanes")));
        assert!(!same_configuration(&record("f32", "Lanes"), &record("f16", "Lanes")));
    }
}
