//! Host-visible buffers kept with a plan and reused by every run: one the host writes a run's inputs into
//! (mapped for writing again as soon as the run's copies out of it are done), one the run's outputs are copied
//! into for the host to read. Nothing host-visible is allocated per run, and a run's inputs are written
//! straight into mapped memory.

use super::mapping::Mapping;
use super::Gpu;
use crate::error::{EngineError, Result};

/// An upload and a readback buffer, used by one run at a time: a plan keeps a few, so that the host can fill
/// the next run's inputs while the last run's outputs wait to be read.
pub(crate) struct Staging {
    /// MAP_WRITE | COPY_SRC; mapped whenever no run is using it.
    upload: wgpu::Buffer,
    upload_mapping: Mapping,
    /// MAP_READ | COPY_DST.
    readback: wgpu::Buffer,
    readback_mapping: Mapping,
}

impl Staging {
    /// Staging of `upload_bytes` and `readback_bytes`, counted in the Gpu's counters; the upload buffer starts
    /// mapped.
    pub(crate) fn new(gpu: &Gpu, upload_bytes: u64, readback_bytes: u64) -> Staging {
        let usage = wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC;
        let upload = gpu.create_buffer_mapped("upload staging", upload_bytes, usage);
        let usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        let readback = gpu.create_buffer("readback staging", readback_bytes, usage);
        Staging { upload, upload_mapping: Mapping::mapped(), readback, readback_mapping: Mapping::default() }
    }

    pub(crate) fn upload(&self) -> &wgpu::Buffer {
        &self.upload
    }

    pub(crate) fn readback(&self) -> &wgpu::Buffer {
        &self.readback
    }

    /// Waits until the upload buffer is mapped for writing (its last run's copies are done). False when its
    /// mapping failed: the staging is not to be used again.
    pub(crate) async fn upload_ready(&self, gpu: &Gpu) -> Result<bool> {
        if self.upload_mapping.outcome().is_none() {
            gpu.poll()?;
        }
        Ok(self.upload_mapping.settled().await)
    }

    /// After the submit that copies out of the upload buffer and into the readback buffer: maps both again,
    /// each once the GPU is done with it.
    pub(crate) fn submitted(&mut self) {
        self.upload_mapping = Mapping::request(&self.upload.slice(..), wgpu::MapMode::Write);
        self.readback_mapping = Mapping::request(&self.readback.slice(..), wgpu::MapMode::Read);
    }

    /// Waits for `submission` (the run that filled the readback buffer) and its mappings.
    pub(crate) async fn wait_readback(&self, gpu: &Gpu, submission: wgpu::SubmissionIndex) -> Result<()> {
        gpu.device
            .poll(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
            .map_err(|e| EngineError::Device(format!("waiting for the GPU: {e}")))?;
        if self.readback_mapping.outcome().is_none() {
            gpu.poll()?;
        }
        match self.readback_mapping.settled().await {
            true => Ok(()),
            false => Err(EngineError::Device("mapping a readback buffer failed".into())),
        }
    }
}
