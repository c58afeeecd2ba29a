//! Running a built [`Plan`]: all ops in one compute pass and one submit (with the scene's copies and the
//! readback in the same submit: [`Plan::execute_and_read`]), op by op for profiling, or op by op reading back
//! what each wrote (debugging, and finding where a non-finite value came from).

use std::sync::atomic::Ordering;

use super::{Plan, PlannedOp, TensorId};
use crate::error::{EngineError, Result};
use crate::gpu::{Gpu, ReadPart, TimestampMode};
use crate::tensor::GpuTensor;

/// What one op wrote, read back by [`Plan::execute_debug`].
pub struct OpOutput {
    pub op: String,
    pub tensor: String,
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f32>,
}

impl Plan {
    /// Records `ops` into one compute pass and submits it.
    fn record(&self, gpu: &Gpu, ops: &[PlannedOp]) {
        let encoder = self.encode(gpu, ops);
        gpu.queue.submit([encoder.finish()]);
        gpu.counters.submits.fetch_add(1, Ordering::Relaxed);
    }

    /// Records `ops` into one compute pass, with GPU timestamps when the Gpu's [`TimestampMode`] asks for them:
    /// at the pass's start and end, or also between every two ops.
    fn encode(&self, gpu: &Gpu, ops: &[PlannedOp]) -> wgpu::CommandEncoder {
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        self.encode_pass(gpu, &mut encoder, ops);
        encoder
    }

    /// Records every op of the plan into `encoder` as one compute pass (timed as [`encode`](Self::encode)
    /// says), for a caller that adds its own copies around it in the same submit.
    pub(crate) fn encode_into(&self, gpu: &Gpu, encoder: &mut wgpu::CommandEncoder) {
        self.encode_pass(gpu, encoder, &self.ops);
    }

    fn encode_pass(&self, gpu: &Gpu, encoder: &mut wgpu::CommandEncoder, ops: &[PlannedOp]) {
        let mut timestamps = gpu.timestamps.lock().expect("timestamps poisoned");
        let mode = timestamps.mode;
        let queries = match mode {
            TimestampMode::Off => 0,
            TimestampMode::Plan => 2,
            TimestampMode::Ops => ops.len() as u32 + 1,
        };
        timestamps.reserve(&gpu.device, queries);
        {
            let pass_writes = (mode == TimestampMode::Plan).then(|| {
                let (query_set, _) = timestamps.slot(0);
                wgpu::ComputePassTimestampWrites {
                    query_set,
                    beginning_of_pass_write_index: Some(0),
                    end_of_pass_write_index: Some(1),
                }
            });
            let mut pass =
                encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: pass_writes });
            for (i, op) in ops.iter().enumerate() {
                if mode == TimestampMode::Ops {
                    let (set, index) = timestamps.slot(i as u32);
                    pass.write_timestamp(set, index);
                }
                pass.set_pipeline(&op.pipeline);
                pass.set_bind_group(0, &op.bind_group, &[]);
                let [x, y, z] = op.workgroups;
                pass.dispatch_workgroups(x, y, z);
            }
            if mode == TimestampMode::Ops {
                let (set, index) = timestamps.slot(ops.len() as u32);
                pass.write_timestamp(set, index);
            }
        }
        if mode != TimestampMode::Off {
            let names = match mode {
                TimestampMode::Ops => {
                    ops.iter().map(|o| (o.label.clone(), format!("{}.{}", o.shader, o.entry))).collect()
                }
                _ => Vec::new(),
            };
            timestamps.resolve(encoder, queries, names);
        }
        drop(timestamps);
        gpu.counters.dispatches.fetch_add(ops.len() as u64, Ordering::Relaxed);
    }

    /// Runs every op, then copies each `(tensor, into)` of `copies` into `into` (a buffer of the same size
    /// that outlives the plan) and reads back the `reads`, all in one submit; waits for the GPU. The values
    /// are row-major `[rows, cols]` matrices, row padding removed.
    pub async fn execute_and_read_async(
        &self,
        gpu: &Gpu,
        copies: &[(TensorId, &GpuTensor)],
        reads: &[TensorId],
    ) -> Result<Vec<Vec<f32>>> {
        let mut encoder = self.encode(gpu, &self.ops);
        for &(id, into) in copies {
            let from = &self.buffers[id.0];
            assert_eq!(from.size(), into.buffer.size(), "copying {} out of the plan", self.infos[id.0].0);
            encoder.copy_buffer_to_buffer(from, 0, &into.buffer, 0, from.size());
        }
        let parts: Vec<ReadPart> = reads
            .iter()
            .map(|id| ReadPart {
                buffer: &self.buffers[id.0],
                row_start: 0,
                rows: self.infos[id.0].1,
                cols: self.infos[id.0].2,
            })
            .collect();
        gpu.submit_and_read(encoder, &parts).await
    }

    /// Records every op into one compute pass and submits it. Returns without waiting for the GPU.
    pub fn execute(&self, gpu: &Gpu) {
        self.record(gpu, &self.ops);
    }

    /// Runs the ops one submit at a time, waiting for each, and returns each op's label and wall time.
    /// Slower than [`execute`](Self::execute) (a submit and a wait per op); for finding where time goes.
    pub async fn profile_async(&self, gpu: &Gpu) -> Result<Vec<(String, std::time::Duration)>> {
        let mut times = Vec::with_capacity(self.ops.len());
        for op in &self.ops {
            let start = web_time::Instant::now();
            self.record(gpu, std::slice::from_ref(op));
            gpu.finished().await?;
            times.push((op.label.clone(), start.elapsed()));
        }
        Ok(times)
    }

    /// Runs the ops one submit at a time and reads back every tensor each op wrote, in order.
    pub async fn execute_debug_async(&self, gpu: &Gpu) -> Result<Vec<OpOutput>> {
        let mut outputs = Vec::new();
        self.run_debug(gpu, |output| {
            outputs.push(output);
            true
        })
        .await?;
        Ok(outputs)
    }

    /// Runs the ops one at a time and returns the first op output holding NaN or infinity, if any: where a
    /// render that came out non-finite went wrong.
    pub async fn first_non_finite_async(&self, gpu: &Gpu) -> Result<Option<OpOutput>> {
        let mut found = None;
        self.run_debug(gpu, |output| {
            if output.data.iter().all(|v| v.is_finite()) {
                return true;
            }
            found = Some(output);
            false
        })
        .await?;
        Ok(found)
    }

    /// Runs the ops one submit at a time, handing what each wrote to `visit` until it returns false.
    async fn run_debug(&self, gpu: &Gpu, mut visit: impl FnMut(OpOutput) -> bool) -> Result<()> {
        for op in &self.ops {
            self.record(gpu, std::slice::from_ref(op));
            for view in &op.written {
                let (name, _, cols, _) = &self.infos[view.id.0];
                let data = gpu.read_rows_async(&self.buffers[view.id.0], view.row_start, view.rows, *cols).await?;
                let output =
                    OpOutput { op: op.label.clone(), tensor: name.clone(), rows: view.rows, cols: *cols, data };
                if !visit(output) {
                    return Ok(());
                }
            }
        }
        Ok(())
    }

    /// Checks values read back from this plan: when any is NaN or infinity, finds the op where they first
    /// appear and reports it (`what` names the render or encode).
    pub async fn check_finite_async(&self, gpu: &Gpu, what: &str, values: &[f32]) -> Result<()> {
        if values.iter().all(|v| v.is_finite()) {
            return Ok(());
        }
        Err(self.non_finite_async(gpu, what).await)
    }

    /// The error of a run whose outputs were NaN or infinite: runs the ops one by one (on the inputs as they
    /// are) to name the op where such values first appear.
    pub async fn non_finite_async(&self, gpu: &Gpu, what: &str) -> EngineError {
        let culprit = match self.first_non_finite_async(gpu).await {
            Ok(culprit) => culprit,
            Err(e) => return e,
        };
        let (op, tensor) = culprit.map_or(("(not reproduced op by op)".into(), "?".into()), |o| (o.op, o.tensor));
        EngineError::NonFinite { what: what.to_string(), op, tensor }
    }
}
