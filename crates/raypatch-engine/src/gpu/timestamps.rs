//! GPU timestamps around executed plans and between their ops: what [`Gpu::set_timestamps`] turns on and
//! [`Gpu::take_timestamps`] reads (the benchmark's GPU times; `plan/execute.rs` writes them).

use std::time::Duration;

use super::Gpu;
use crate::error::{EngineError, Result};

/// Whether executed plans are timed on the GPU (see [`Gpu::set_timestamps`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TimestampMode {
    #[default]
    Off,
    /// A timestamp at the start and the end of each executed plan's compute pass.
    Plan,
    /// Also one between every two ops (needs `TIMESTAMP_QUERY_INSIDE_PASSES`).
    Ops,
}

/// GPU time of the last timed plan: its whole pass and, in [`TimestampMode::Ops`], each op in order.
#[derive(Clone, Debug)]
pub struct GpuTimes {
    pub total: Duration,
    pub ops: Vec<OpTime>,
}

#[derive(Clone, Debug)]
pub struct OpTime {
    pub label: String,
    /// `shader.entry`, e.g. `matmul.linear`.
    pub kernel: String,
    pub time: Duration,
}

/// Queries per query set (wgpu's `QUERY_SET_MAX_QUERIES`); plans with more ops use several sets.
const QUERIES_PER_SET: u32 = 4096;

/// Query sets and buffers for GPU timestamps, grown on demand, and what the last timed plan wrote.
#[derive(Default)]
pub(crate) struct Timestamps {
    pub(crate) mode: TimestampMode,
    sets: Vec<wgpu::QuerySet>,
    /// Resolved ticks (QUERY_RESOLVE) and their host-mappable copy, `8 · QUERIES_PER_SET` bytes per set.
    buffers: Option<(wgpu::Buffer, wgpu::Buffer)>,
    /// Queries written by the last timed plan, and its ops' (label, kernel) in Ops mode.
    pending: Option<(u32, Vec<(String, String)>)>,
}

impl Timestamps {
    /// Makes room for `queries` timestamps. Its buffers are not counted in
    /// [`GpuCounters`](super::GpuCounters): they belong to the measurement, not to the work measured.
    pub(crate) fn reserve(&mut self, device: &wgpu::Device, queries: u32) {
        let sets_needed = queries.div_ceil(QUERIES_PER_SET) as usize;
        if self.sets.len() >= sets_needed {
            return;
        }
        while self.sets.len() < sets_needed {
            self.sets.push(device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: QUERIES_PER_SET,
            }));
        }
        let bytes = self.sets.len() as u64 * QUERIES_PER_SET as u64 * 8;
        let buffer = |label, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        self.buffers = Some((
            buffer("timestamps", wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC),
            buffer("timestamps readback", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
        ));
    }

    /// The query set and index of timestamp `i`.
    pub(crate) fn slot(&self, i: u32) -> (&wgpu::QuerySet, u32) {
        (&self.sets[(i / QUERIES_PER_SET) as usize], i % QUERIES_PER_SET)
    }

    /// Records the copy of `queries` timestamps to the host-mappable buffer; `ops` names the ops (label,
    /// kernel) between them.
    pub(crate) fn resolve(&mut self, encoder: &mut wgpu::CommandEncoder, queries: u32, ops: Vec<(String, String)>) {
        let (resolve, readback) = self.buffers.as_ref().expect("timestamps reserved before use");
        for (s, set) in self.sets.iter().enumerate() {
            let first = s as u32 * QUERIES_PER_SET;
            if first >= queries {
                break;
            }
            let count = (queries - first).min(QUERIES_PER_SET);
            encoder.resolve_query_set(set, 0..count, resolve, first as u64 * 8);
        }
        encoder.copy_buffer_to_buffer(resolve, 0, readback, 0, queries as u64 * 8);
        self.pending = Some((queries, ops));
    }
}

impl Gpu {
    /// Times every plan executed from now on with GPU timestamps (read them with
    /// [`take_timestamps`](Self::take_timestamps)), or stops. An error if the adapter cannot.
    pub fn set_timestamps(&self, mode: TimestampMode) -> Result<()> {
        let needs = match mode {
            TimestampMode::Off => wgpu::Features::empty(),
            TimestampMode::Plan => wgpu::Features::TIMESTAMP_QUERY,
            TimestampMode::Ops => wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES,
        };
        if !self.features.contains(needs) {
            return Err(EngineError::Device(format!("{} has no {needs:?}", self.info.name)));
        }
        let mut timestamps = self.timestamps.lock().expect("timestamps poisoned");
        timestamps.mode = mode;
        timestamps.pending = None;
        Ok(())
    }

    /// The GPU times of the last plan executed with timestamps on, if any since the last call, once the GPU
    /// is done.
    pub async fn take_timestamps_async(&self) -> Result<Option<GpuTimes>> {
        let (queries, names, readback) = {
            let mut timestamps = self.timestamps.lock().expect("timestamps poisoned");
            let Some((queries, names)) = timestamps.pending.take() else {
                return Ok(None);
            };
            let (_, readback) = timestamps.buffers.as_ref().expect("timestamps were resolved");
            (queries, names, readback.clone())
        };
        let slice = readback.slice(..queries as u64 * 8);
        self.map_for_reading(&slice, "the timestamps").await?;
        let ticks: Vec<u64> = {
            let mapped =
                slice.get_mapped_range().map_err(|e| EngineError::Device(format!("reading timestamps: {e}")))?;
            bytemuck::cast_slice(&mapped).to_vec()
        };
        readback.unmap();
        let period = self.queue.get_timestamp_period() as f64;
        let span = |a: u64, b: u64| Duration::from_nanos((b.saturating_sub(a) as f64 * period).round() as u64);
        let total = span(ticks[0], ticks[queries as usize - 1]);
        let ops = names
            .into_iter()
            .zip(ticks.windows(2))
            .map(|((label, kernel), t)| OpTime { label, kernel, time: span(t[0], t[1]) })
            .collect();
        Ok(Some(GpuTimes { total, ops }))
    }
}
