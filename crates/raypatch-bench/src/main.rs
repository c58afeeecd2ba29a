//! `raypatch-bench [--quick] --out DIR`: measures raypatch and writes results.json, results.csv,
//! kernels.csv, tables.md and PNG plots into DIR.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

#[derive(Parser)]
#[command(
    version,
    about = "Benchmark raypatch: run time against error, memory, FLOPs; JSON, CSV and plots"
)]
struct Args {
    /// The smoke-test subset: small models, a few sizes, one official-size configuration (< 2 min on lavapipe).
    #[arg(long)]
    quick: bool,
    /// Folder for results.json, results.csv, kernels.csv, tables.md and the plots.
    #[arg(long)]
    out: PathBuf,
    /// Use the first adapter whose name contains this text.
    #[arg(long)]
    adapter: Option<String>,
    /// Measured runs per configuration, after a warm-up (default 5, quick 3).
    #[arg(long)]
    repeats: Option<usize>,
    /// Skip sizes whose render is predicted to take longer than this many seconds (default 120, quick 1.5).
    #[arg(long)]
    max_render_seconds: Option<f64>,
    /// Do not time PyTorch even if it is installed.
    #[arg(long)]
    no_pytorch: bool,
    /// A model file to measure too (repeatable), e.g. a trained model.
    #[arg(long = "model")]
    models: Vec<PathBuf>,
    /// The scene for --model files (default: a synthetic 120x160 scene).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Measure nothing: write tables.md and the plots into --out again from this results.json.
    #[arg(long, value_name = "RESULTS_JSON")]
    replot: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    if args.repeats == Some(0) {
        eprintln!("raypatch-bench: --repeats must be at least 1");
        return ExitCode::from(2);
    }
    if let Some(results) = &args.replot {
        return match raypatch_bench::replot(results, &args.out) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("raypatch-bench: {e:#}");
                ExitCode::from(2)
            }
        };
    }
    let options = raypatch_bench::Options {
        quick: args.quick,
        out: args.out,
        adapter: args.adapter,
        repeats: args.repeats,
        max_render_seconds: args.max_render_seconds,
        pytorch: !args.no_pytorch,
        models: args.models,
        scene: args.scene,
        command: std::env::args().collect::<Vec<_>>().join(" "),
    };
    match raypatch_bench::run(&options) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("raypatch-bench: {e:#}");
            ExitCode::from(2)
        }
    }
}
