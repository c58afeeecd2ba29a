//! raypatch's benchmark harness: per configuration (model, patch size, target size, precision, skips) the
//! encode and render times (GPU timestamps where the adapter has them), planned peak memory, FLOPs per
//! frame (counted by the engine from the ops its plans record), and the error against a float64 CPU
//! reference, against PyTorch and against ground truth; results as JSON, CSV, Markdown tables and PNG plots.
//! `raypatch-bench --quick --out DIR` is the smoke test.

pub mod coop_tune;
pub mod flops;
pub mod gemm;
pub mod gemm_lab;
pub mod harness;
pub mod kernels;
pub mod measure;
pub mod paper;
pub mod plots;
pub mod pytorch;
pub mod report;
pub mod synthetic;

pub use harness::{replot, run, Options};
