//! raypatch's benchmark harness: per configuration (model, patch size, target size, precision, skips) the
//! encode and render times, planned peak memory, FLOPs per frame and the error against a float64 CPU
//! reference, against PyTorch and against ground truth; results as JSON, CSV and plots.

pub mod synthetic;
