//! Saving a Lightning checkpoint's model as a raypatch model file, without Python: the file
//! `tools/conversion/convert_checkpoint.py` writes for it, tensor for tensor and byte for byte.

use std::path::Path;

use crate::error::{Error, Result};

/// Reads the checkpoint `checkpoint` (an official Lightning `.ckpt`), checks every tensor the model needs by
/// name, shape and value as loading it does (no GPU needed), and writes the model file to `out` atomically.
/// Returns the number of tensors written. `out` may not be the checkpoint itself, and the input must be a
/// checkpoint (a model file is already one).
pub fn save_checkpoint_model(checkpoint: &Path, out: &Path) -> Result<usize> {
    let refuse = |reason: &str| Error::io(out, "cannot write", std::io::Error::other(reason.to_string()));
    if crate::output::same_file(checkpoint, out) {
        return Err(refuse("is the input checkpoint itself: choose another output path"));
    }
    crate::output::check_output_path(out)?;
    let loaded = raypatch_model::load_model(checkpoint)?;
    // Only a checkpoint's model file is held in memory when loaded from a path.
    let Some(bytes) = loaded.file_bytes() else {
        return Err(refuse(&format!(
            "{} is already a model .safetensors file, not a checkpoint",
            checkpoint.display()
        )));
    };
    // Builds the model's module tree over the file: every tensor fetched by name and shape, none left over.
    raypatch_engine::models::build(&loaded, raypatch_engine::nn::ReadLimits::NONE)?;
    crate::output::write_atomic(out, bytes)?;
    Ok(loaded.tensor_count())
}
