//! A render's recording (`record_render`: the family's render and a readout per output) and what the host
//! writes into a render plan and reads out of it, through staging buffers kept with the plan:
//! - the target cameras and given rays are written straight into the plan's mapped upload buffer (rows padded
//!   as they are copied; a NaN or infinity is caught in that same pass, so no kernel ever sees one); a pinhole
//!   camera's rays are made on the GPU from its column and row terms (`kernels::rays`);
//! - one submit copies them in, runs the plan, and copies out each output's region, which the plan's readout
//!   ops (`kernels::readout`) packed densely on the GPU, with a flag raised for any non-finite value;
//! - the host copies each view's values once out of the mapped readback buffer into the vectors it returns.
//!
//! A plan keeps a few stagings, so that a run can be submitted while the last one waits to be read
//! ([`RenderPlan::submit`], then [`Submitted::finish`]): runs of one plan still execute in submission order,
//! which is what lets them share the plan's other buffers.

use std::sync::{Arc, Mutex};

use raypatch_model::pinhole::PinholeRays;
use raypatch_model::{RaySource, TargetGrid, TargetRays, TargetViews};

use crate::error::{EngineError, Result};
use crate::frame::{Crop, Frame, Output, OutputValues, Outputs, Region};
use crate::gpu::{Gpu, Staging};
use crate::graph::{Graph, HostInput, Tensor};
use crate::kernels::readout::{read_region, ReadoutArgs, WINDOW_WORDS};
use crate::models::LightField;
use crate::plan::{Plan, PlanBuilder, TensorId};
use crate::tensor::GpuTensor;

/// Bytes the readback buffer holds ahead of the outputs: the non-finite flag (one word, padded).
const FLAG_BYTES: u64 = 16;

/// A built render plan with its host inputs, its readouts and its stagings.
pub(crate) struct RenderPlan {
    pub plan: Plan,
    pub io: RenderIo,
    pub largest_tensor_bytes: u64,
    /// Held while a run is submitted, and while a run whose outputs were not finite is replayed op by op: the
    /// replay must see that run's inputs.
    pub in_use: Mutex<()>,
    /// Stagings not in use by a submitted run.
    staging: Mutex<Vec<Staging>>,
    upload_bytes: u64,
    readback_bytes: u64,
}

/// What the host writes into and reads from a render plan, and how many decoder queries it runs.
pub(crate) struct RenderIo {
    pub host_inputs: Vec<(TensorId, HostInput)>,
    pub outputs: Vec<Readout>,
    /// The readouts' non-finite flag.
    pub flag: TensorId,
    pub queries: usize,
}

/// An output as the plan's readout packs it: `[views, region height, region width, channels]`, dense.
pub(crate) struct Readout {
    pub output: Output,
    pub channels: usize,
    pub dense: TensorId,
}

/// Records the readout of each rendered output of `views` views of a `height`x`width` grid; the outputs
/// become transients (only the readout reads them).
pub(crate) fn record_readouts(
    g: &mut Graph,
    views: usize,
    (height, width): (usize, usize),
    rendered: &[(Output, Tensor)],
) -> (Vec<Readout>, TensorId) {
    let window = g.input("readout.window", 1, WINDOW_WORDS, HostInput::ReadWindow, None);
    let flag = g.input("readout.flag", 1, 1, HostInput::Zeros, None);
    let mut readouts = Vec::with_capacity(rendered.len());
    for &(output, tensor) in rendered {
        assert_eq!(tensor.view.row_start, 0, "output {} is a view into a tensor", output.name());
        let channels = tensor.cols;
        let dense = g.output(&format!("{}.readout", output.name()), (views * height * width * channels).div_ceil(4), 4);
        let args =
            ReadoutArgs { x: tensor.view, views, height, width, out: dense.view, window: window.view, flag: flag.view };
        read_region(&mut g.b, &format!("readout.{}", output.name()), args);
        g.b.make_transient(tensor.id());
        readouts.push(Readout { output, channels, dense: dense.id() });
    }
    (readouts, flag.id())
}

/// Records the render of `views` target views on `grid` of a scene whose cached tensors are `cached`.
pub(crate) fn record_render(
    mut g: Graph,
    family: &dyn LightField,
    cached: &[GpuTensor],
    views: usize,
    grid: TargetGrid,
    outputs: Outputs,
) -> Recorded {
    let rendered = family.render(&mut g, cached, views, grid, outputs);
    let (outputs, flag) = record_readouts(&mut g, views, (grid.height, grid.width), &rendered);
    let Graph { b, host_inputs, .. } = g;
    let k = family.patch_size();
    let queries = views * (grid.height / k) * (grid.width / k);
    Recorded { builder: b, io: RenderIo { host_inputs, outputs, flag, queries } }
}

/// The recording of what a first render of `(height, width)` likely is: one view from a pinhole camera, rgb
/// where the model has it, over a scene whose cached tensors are `cached`; `None` for a size that no render
/// computes whole. Its pipelines are compiled before that render asks for them (`model.rs`).
pub(crate) fn first_render(
    g: Graph,
    family: &dyn LightField,
    cached: &[GpuTensor],
    (height, width): (usize, usize),
) -> Option<PlanBuilder> {
    let k = family.patch_size();
    if !height.is_multiple_of(k) || !width.is_multiple_of(k) {
        return None;
    }
    let grid = TargetGrid { height, width, rays: RaySource::Pinhole };
    let rgb = Outputs::of(&[Output::Rgb]);
    let outputs = if family.outputs().contains(Output::Rgb) { rgb } else { family.outputs() };
    Some(record_render(g, family, cached, 1, grid, outputs).builder)
}

/// A render recorded but not built.
pub(crate) struct Recorded {
    pub builder: PlanBuilder,
    pub io: RenderIo,
}

/// A run submitted and not read yet.
pub(crate) struct Submitted {
    plan: Arc<RenderPlan>,
    staging: Staging,
    submission: wgpu::SubmissionIndex,
    crop: Crop,
    views: usize,
}

impl RenderPlan {
    pub(crate) fn new(builder: PlanBuilder, io: RenderIo, gpu: &Gpu) -> Result<RenderPlan> {
        let largest_tensor_bytes = builder.largest_tensor_bytes();
        let plan = builder.build(gpu)?;
        let upload_bytes = io.host_inputs.iter().map(|(id, _)| plan.tensor_bytes(*id)).sum();
        let readback_bytes = FLAG_BYTES + io.outputs.iter().map(|r| plan.tensor_bytes(r.dense)).sum::<u64>();
        Ok(RenderPlan {
            plan,
            io,
            largest_tensor_bytes,
            in_use: Mutex::new(()),
            staging: Mutex::new(Vec::new()),
            upload_bytes,
            readback_bytes,
        })
    }

    /// Bytes of one staging (upload and readback): what each run in flight holds besides the plan.
    pub(crate) fn staging_bytes(&self) -> u64 {
        self.upload_bytes + self.readback_bytes
    }

    /// Writes the inputs of `views` target views of `crop` (rays `per_ray` pixels apart) and submits the run
    /// with its copies in and out. Returns without waiting for the GPU.
    pub(crate) async fn submit(
        self: &Arc<Self>,
        gpu: &Gpu,
        targets: &TargetViews,
        crop: &Crop,
        per_ray: usize,
    ) -> Result<Submitted> {
        let mut staging = self.take_staging(gpu).await?;
        if !self.write_inputs(&staging, targets, crop, per_ray)? {
            // Nothing was submitted; the staging, unmapped, is dropped. Name the value.
            targets.check_finite("target views")?;
            return Err(EngineError::Request("target views hold a value that is not finite".into()));
        }
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let mut at = 0;
        for (id, _) in &self.io.host_inputs {
            let bytes = self.plan.tensor_bytes(*id);
            encoder.copy_buffer_to_buffer(staging.upload(), at, self.plan.buffer(*id), 0, bytes);
            at += bytes;
        }
        self.plan.encode_into(gpu, &mut encoder);
        let readback = staging.readback();
        encoder.copy_buffer_to_buffer(self.plan.buffer(self.io.flag), 0, readback, 0, 4);
        let values = targets.count * crop.region.height * crop.region.width;
        let mut at = FLAG_BYTES;
        for r in &self.io.outputs {
            let bytes = (values * r.channels * 4) as u64;
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(self.plan.buffer(r.dense), 0, readback, at, bytes);
            }
            at += self.plan.tensor_bytes(r.dense);
        }
        let submission = {
            let _turn = self.in_use.lock().expect("render plan poisoned");
            gpu.submit(encoder)
        };
        staging.submitted();
        Ok(Submitted { plan: self.clone(), staging, submission, crop: *crop, views: targets.count })
    }

    /// A staging whose upload buffer is mapped: a kept one, else a new one (a first run, or more runs in flight
    /// than ever before).
    async fn take_staging(&self, gpu: &Gpu) -> Result<Staging> {
        loop {
            let Some(staging) = self.staging.lock().expect("stagings poisoned").pop() else { break };
            if staging.upload_ready(gpu).await? {
                return Ok(staging);
            }
        }
        Ok(Staging::new(gpu, self.upload_bytes, self.readback_bytes))
    }

    /// Writes every host input into the staging's upload buffer and unmaps it; false when a camera position
    /// or ray is not finite (nothing may reach the kernels then).
    fn write_inputs(&self, staging: &Staging, targets: &TargetViews, crop: &Crop, per_ray: usize) -> Result<bool> {
        let upload = staging.upload();
        let mut finite = true;
        {
            let mut view = upload
                .get_mapped_range_mut(..self.upload_bytes)
                .map_err(|e| EngineError::Device(format!("writing a render's inputs: {e}")))?;
            let mut rest = view.slice(..);
            for (id, input) in &self.io.host_inputs {
                let bytes = self.plan.tensor_bytes(*id) as usize;
                let (part, after) = std::mem::take(&mut rest).split_at(bytes);
                rest = after;
                let (rows, _) = part.into_chunks::<16>();
                match input {
                    HostInput::TargetCameraPos => {
                        let positions = targets.camera_pos.chunks_exact(3).map(|p| [p[0], p[1], p[2]]);
                        finite &= write_rows(rows, positions)
                    }
                    HostInput::TargetRays => {
                        // Pinhole cameras' rays land here only on a GPU that does not make them: made on the host.
                        finite &= write_rows(rows, crop.rays(&targets.ray_values(), per_ray))
                    }
                    HostInput::TargetPinholes => {
                        if let TargetRays::Pinhole(cameras) = &targets.rays {
                            finite &= cameras.iter().all(PinholeRays::is_finite);
                        }
                        rows.write_iter(crop.pinhole_terms(targets).flat_map(bytemuck::cast::<_, [[u8; 16]; 2]>));
                    }
                    HostInput::ReadWindow => rows.write_iter([bytemuck::cast(crop.read_window())]),
                    HostInput::Zeros => rows.write_iter(std::iter::repeat_n([0u8; 16], bytes / 16)),
                    other => unreachable!("a render reads only target views, not {other:?}"),
                }
            }
        }
        upload.unmap();
        Ok(finite)
    }

    /// Writes the target views' inputs with [`Gpu::write`] (no staging): for running the plan op by op.
    pub(crate) fn write_inputs_directly(
        &self,
        gpu: &Gpu,
        targets: &TargetViews,
        crop: &Crop,
        per_ray: usize,
    ) -> Result<()> {
        targets.check_finite("target views")?;
        for (id, input) in &self.io.host_inputs {
            let tensor = self.plan.tensor(*id);
            let values: Vec<f32> = match input {
                HostInput::TargetCameraPos => targets.camera_pos.clone(),
                HostInput::TargetRays => crop.rays(&targets.ray_values(), per_ray).flatten().collect(),
                HostInput::TargetPinholes => crop.pinhole_terms(targets).flatten().collect(),
                HostInput::ReadWindow => crop.read_window().map(f32::from_bits).to_vec(),
                HostInput::Zeros => vec![0.0; tensor.rows * tensor.cols],
                other => unreachable!("a render reads only target views, not {other:?}"),
            };
            gpu.write(&tensor, &values);
        }
        Ok(())
    }
}

/// Writes rows of three floats as rows of four (the fourth zero: the engine's row padding); whether every
/// value was finite. `rows` must give exactly as many rows as `dst` holds.
fn write_rows(dst: wgpu::WriteOnly<'_, [[u8; 16]]>, rows: impl Iterator<Item = [f32; 3]>) -> bool {
    let mut finite = true;
    dst.write_iter(rows.map(|r| {
        finite &= r[0].is_finite() & r[1].is_finite() & r[2].is_finite();
        bytemuck::cast([r[0], r[1], r[2], 0.0f32])
    }));
    finite
}

/// Where the values of a render's runs go: per output, one vector for all views (`[views, height, width,
/// channels]`), or one per view; filled band by band.
pub(crate) struct Sink {
    per_view: bool,
    views: usize,
    region: Region,
    /// `[part][output]`: a part is the whole batch, or one view.
    values: Vec<Vec<OutputValues>>,
}

impl Sink {
    pub(crate) fn new(plan: &RenderPlan, views: usize, region: Region, per_view: bool) -> Sink {
        let parts = if per_view { views } else { 1 };
        let per_part = region.height * region.width * views / parts;
        let values = (0..parts)
            .map(|_| {
                (plan.io.outputs.iter())
                    .map(|r| OutputValues {
                        output: r.output,
                        channels: r.channels,
                        values: Vec::with_capacity(per_part * r.channels),
                    })
                    .collect()
            })
            .collect();
        Sink { per_view, views, region, values }
    }

    /// The frames: one per view, or one of every view.
    pub(crate) fn frames(self) -> Vec<Frame> {
        let Sink { per_view, views, region, values } = self;
        let views = if per_view { 1 } else { views };
        values
            .into_iter()
            .map(|outputs| Frame { views, height: region.height, width: region.width, region, outputs })
            .collect()
    }
}

impl Submitted {
    pub(crate) fn plan(&self) -> &Arc<RenderPlan> {
        &self.plan
    }

    pub(crate) fn crop(&self) -> &Crop {
        &self.crop
    }

    /// Waits for the run and copies each view's values of each output once out of the mapped readback buffer
    /// into `sink`. False when the readout flagged a NaN or infinity (nothing is copied then).
    pub(crate) async fn finish(self, gpu: &Gpu, sink: &mut Sink) -> Result<bool> {
        let Submitted { plan, staging, submission, crop, views } = self;
        staging.wait_readback(gpu, submission).await?;
        let readback = staging.readback();
        let finite = {
            let mapped = readback
                .get_mapped_range(..)
                .map_err(|e| EngineError::Device(format!("reading a render back: {e}")))?;
            let words: &[f32] = bytemuck::cast_slice(&mapped);
            let finite = words[0].to_bits() == 0;
            if finite {
                let band = crop.region;
                let row = band.y - sink.region.y;
                let mut at = (FLAG_BYTES / 4) as usize;
                for (o, r) in plan.io.outputs.iter().enumerate() {
                    let per_view = band.height * band.width * r.channels;
                    for v in 0..views {
                        let from = &words[at + v * per_view..at + (v + 1) * per_view];
                        let (part, into) = if sink.per_view {
                            (v, row * band.width * r.channels)
                        } else {
                            (0, (v * sink.region.height + row) * band.width * r.channels)
                        };
                        place(&mut sink.values[part][o].values, into, from);
                    }
                    at += (plan.plan.tensor_bytes(r.dense) / 4) as usize;
                }
            }
            finite
        };
        readback.unmap();
        plan.staging.lock().expect("stagings poisoned").push(staging);
        Ok(finite)
    }
}

/// Copies `from` into `into..` of `values`: appended when it comes next (a render in one band, or views kept
/// apart), else into its place (bands of views kept together), zeros standing for the parts still to come.
fn place(values: &mut Vec<f32>, into: usize, from: &[f32]) {
    if values.len() < into {
        values.resize(into, 0.0);
    }
    if values.len() == into {
        values.extend_from_slice(from);
    } else {
        values[into..into + from.len()].copy_from_slice(from);
    }
}
