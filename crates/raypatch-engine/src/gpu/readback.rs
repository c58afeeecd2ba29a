//! Reading tensors back from the GPU: copies into one kept readback buffer, one submit, then the mapping awaited
//! ([`Mapping`]: blocking on native, a browser's event loop on the web).

use std::sync::atomic::Ordering;

use super::mapping::Mapping;
use super::Gpu;
use crate::error::{EngineError, Result};
use crate::tensor::{padded_cols, GpuTensor};

/// Rows `[row_start, row_start + rows)` of a `cols`-wide f32 tensor stored in `buffer`, to read back
/// ([`Gpu::submit_and_read`]).
pub(crate) struct ReadPart<'a> {
    pub buffer: &'a wgpu::Buffer,
    pub row_start: usize,
    pub rows: usize,
    pub cols: usize,
}

impl Gpu {
    /// Reads a tensor back as a row-major `[rows, cols]` matrix (row padding removed), once the GPU is done.
    pub async fn read_async(&self, tensor: &GpuTensor) -> Result<Vec<f32>> {
        self.read_rows_async(&tensor.buffer, 0, tensor.rows, tensor.cols).await
    }

    /// Reads rows `[row_start, row_start + rows)` of a `cols`-wide tensor stored in `buffer`.
    pub async fn read_rows_async(
        &self,
        buffer: &wgpu::Buffer,
        row_start: usize,
        rows: usize,
        cols: usize,
    ) -> Result<Vec<f32>> {
        let encoder = self.device.create_command_encoder(&Default::default());
        let part = ReadPart { buffer, row_start, rows, cols };
        Ok(self.submit_and_read(encoder, &[part]).await?.remove(0))
    }

    /// Appends copies of `parts` to `encoder`'s work, submits it (one submit), waits for the GPU and returns
    /// each part as a row-major `[rows, cols]` matrix (row padding removed).
    pub(crate) async fn submit_and_read(
        &self,
        mut encoder: wgpu::CommandEncoder,
        parts: &[ReadPart<'_>],
    ) -> Result<Vec<Vec<f32>>> {
        let bytes = |part: &ReadPart| (part.rows * padded_cols(part.cols) * 4) as u64;
        let total: u64 = parts.iter().map(bytes).sum();
        // One readback buffer for these reads (encodes, debugging), kept and grown as needed; taken while in use,
        // so that a read that waits in a browser holds no lock.
        let kept = self.readback.lock().expect("readback buffer poisoned").take();
        let staging = match kept {
            _ if total == 0 => None,
            Some(buffer) if buffer.size() >= total => Some(buffer),
            _ => {
                let usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
                Some(self.create_buffer("readback", total, usage))
            }
        };
        let mut at = 0;
        for part in parts {
            let ld = padded_cols(part.cols);
            if let (Some(staging), n @ 1..) = (&staging, bytes(part)) {
                encoder.copy_buffer_to_buffer(part.buffer, (part.row_start * ld * 4) as u64, staging, at, n);
            }
            at += bytes(part);
        }
        self.queue.submit([encoder.finish()]);
        self.counters.submits.fetch_add(1, Ordering::Relaxed);
        let Some(staging) = staging else {
            return Ok(parts.iter().map(|_| Vec::new()).collect());
        };
        let slice = staging.slice(..total);
        self.map_for_reading(&slice, "a readback buffer").await?;
        let mapped = slice.get_mapped_range().map_err(|e| EngineError::Device(format!("reading back: {e}")))?;
        let mut words: &[f32] = bytemuck::cast_slice(&mapped);
        let mut out = Vec::with_capacity(parts.len());
        for part in parts {
            let ld = padded_cols(part.cols);
            let mut values = Vec::with_capacity(part.rows * part.cols);
            for r in 0..part.rows {
                values.extend_from_slice(&words[r * ld..r * ld + part.cols]);
            }
            words = &words[part.rows * ld..];
            out.push(values);
        }
        drop(mapped);
        staging.unmap();
        *self.readback.lock().expect("readback buffer poisoned") = Some(staging);
        Ok(out)
    }

    /// Maps `slice` for reading once the GPU has finished the work submitted so far; `what` names the buffer
    /// in errors.
    pub(crate) async fn map_for_reading(&self, slice: &wgpu::BufferSlice<'_>, what: &str) -> Result<()> {
        let mapping = Mapping::request(slice, wgpu::MapMode::Read);
        self.poll()?;
        match mapping.settled().await {
            true => Ok(()),
            false => Err(EngineError::Device(format!("mapping {what} failed"))),
        }
    }

    /// Once the GPU has finished all submitted work.
    pub async fn finished(&self) -> Result<()> {
        let done = Mapping::work_done(&self.queue);
        self.poll()?;
        done.settled().await;
        Ok(())
    }

    /// Runs wgpu's callbacks of finished work, blocking until all submitted work is done on native; a no-op in
    /// a browser, whose callbacks run from its event loop (the awaits of [`Mapping`]).
    pub(super) fn poll(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| EngineError::Device(format!("waiting for the GPU: {e}")))
    }
}
