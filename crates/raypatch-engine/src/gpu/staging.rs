//! Host-visible buffers kept with a plan and reused by every run: one the host writes a run's inputs into
//! (mapped for writing again as soon as the run's copies out of it are done), one the run's outputs are copied
//! into for the host to read. Nothing host-visible is allocated per run, and a run's inputs are written
//! straight into mapped memory.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use super::Gpu;
use crate::error::{EngineError, Result};

/// Where a buffer's mapping stands (set by wgpu's map callback).
const PENDING: u8 = 0;
const MAPPED: u8 = 1;
const FAILED: u8 = 2;

/// An upload and a readback buffer, used by one run at a time: a plan keeps a few, so that the host can fill
/// the next run's inputs while the last run's outputs wait to be read.
pub(crate) struct Staging {
    /// MAP_WRITE | COPY_SRC; mapped whenever no run is using it.
    upload: wgpu::Buffer,
    upload_state: Arc<AtomicU8>,
    /// MAP_READ | COPY_DST.
    readback: wgpu::Buffer,
    readback_state: Arc<AtomicU8>,
}

/// A mapping request whose callback records the outcome in `state`.
fn map(buffer: &wgpu::Buffer, mode: wgpu::MapMode, state: &Arc<AtomicU8>) {
    state.store(PENDING, Ordering::Release);
    let state = state.clone();
    buffer.map_async(mode, .., move |result| {
        state.store(if result.is_ok() { MAPPED } else { FAILED }, Ordering::Release);
    });
}

impl Staging {
    /// Staging of `upload_bytes` and `readback_bytes`, counted in the Gpu's counters; the upload buffer starts
    /// mapped.
    pub(crate) fn new(gpu: &Gpu, upload_bytes: u64, readback_bytes: u64) -> Staging {
        let usage = wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC;
        let upload = gpu.create_buffer_mapped("upload staging", upload_bytes, usage);
        let usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        let readback = gpu.create_buffer("readback staging", readback_bytes, usage);
        Staging {
            upload,
            upload_state: Arc::new(AtomicU8::new(MAPPED)),
            readback,
            readback_state: Arc::new(AtomicU8::new(PENDING)),
        }
    }

    pub(crate) fn upload(&self) -> &wgpu::Buffer {
        &self.upload
    }

    pub(crate) fn readback(&self) -> &wgpu::Buffer {
        &self.readback
    }

    /// Waits until the upload buffer is mapped for writing (its last run's copies are done). False when its
    /// mapping failed: the staging is not to be used again.
    pub(crate) fn upload_ready(&self, gpu: &Gpu) -> Result<bool> {
        if self.upload_state.load(Ordering::Acquire) == PENDING {
            gpu.wait()?;
        }
        Ok(self.upload_state.load(Ordering::Acquire) == MAPPED)
    }

    /// After the submit that copies out of the upload buffer and into the readback buffer: maps both again,
    /// each once the GPU is done with it.
    pub(crate) fn submitted(&self) {
        map(&self.upload, wgpu::MapMode::Write, &self.upload_state);
        map(&self.readback, wgpu::MapMode::Read, &self.readback_state);
    }

    /// Waits for `submission` (the run that filled the readback buffer) and its mappings.
    pub(crate) fn wait_readback(&self, gpu: &Gpu, submission: wgpu::SubmissionIndex) -> Result<()> {
        gpu.device
            .poll(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
            .map_err(|e| EngineError::Device(format!("waiting for the GPU: {e}")))?;
        if self.readback_state.load(Ordering::Acquire) == PENDING {
            gpu.wait()?;
        }
        match self.readback_state.load(Ordering::Acquire) {
            MAPPED => Ok(()),
            _ => Err(EngineError::Device("mapping a readback buffer failed".into())),
        }
    }
}
