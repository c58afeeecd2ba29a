//! Measuring one configuration of a model: its float64 references (computed once per target, shared by every
//! precision), the model under test with its encoded scene ([`Subject`]), the encode, render and PyTorch
//! timings, and the errors against the references and PyTorch that fill a [`Record`].

use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Context, Result};
use raypatch_engine::{EncodedScene, Frame, Model, Output, Outputs, Precision, Request};
use raypatch_model::{InputViews, LoadedModel, ModelConfig, TargetViews};
use raypatch_reference::model::{Argument, ReferenceFrame, ReferenceModel, ReferenceScene};

use super::{size_text, Bench};
use crate::flops;
use crate::measure::{self, Repeats, Sample, Stats};
use crate::report::{self, Record};
use crate::{pytorch, synthetic};

/// The float64 references of a model with their encodings: f32-rounded encoding arguments (not in the accuracy
/// run) and float64 ones (the float64 model), and their renders so far, which every precision shares.
pub(super) struct References {
    rounded: Option<(ReferenceModel, ReferenceScene)>,
    exact: (ReferenceModel, ReferenceScene),
    renders: Mutex<Vec<(TargetKey, Arc<ReferenceRender>)>>,
}

/// Which targets a reference render was of: views, height, width and the rays' first and last values (the
/// bench's scenes are the same cameras at each size).
type TargetKey = (usize, usize, usize, u32, u32);

/// A reference render: with f32-rounded arguments (where computed) and of the float64 model.
struct ReferenceRender {
    rounded: Option<ReferenceFrame>,
    exact: ReferenceFrame,
}

impl References {
    /// The references' render of `targets`, computed once.
    fn render(&self, targets: &TargetViews) -> Result<Arc<ReferenceRender>> {
        let rays = targets.ray_values();
        let bits = |v: Option<&f32>| v.map_or(0, |v| v.to_bits());
        let key = (targets.count, targets.rays_height, targets.rays_width, bits(rays.first()), bits(rays.last()));
        if let Some((_, done)) =
            self.renders.lock().expect("reference renders poisoned").iter().find(|(k, _)| *k == key)
        {
            return Ok(done.clone());
        }
        let rounded = match &self.rounded {
            Some((model, scene)) => Some(model.render(scene, targets)?),
            None => None,
        };
        let exact = self.exact.0.render(&self.exact.1, targets)?;
        let render = Arc::new(ReferenceRender { rounded, exact });
        self.renders.lock().expect("reference renders poisoned").push((key, render.clone()));
        Ok(render)
    }
}

/// A model's float64 references, or why there are none (e.g. `too slow at this size`), for the records' notes.
type MaybeReferences = std::result::Result<References, String>;

/// One model under test with its encoded scene (engine and references).
pub(super) struct Subject<'a> {
    pub(super) name: String,
    group: &'static str,
    pub(super) loaded: &'a LoadedModel,
    /// The model as a file, for PyTorch.
    file: Option<&'a [u8]>,
    pub(super) model: &'a Model,
    pub(super) precision: Precision,
    pub(super) inputs: &'a InputViews,
    /// Parsing the model file and loading it on the GPU (the sweep's models, made in memory as files), ms.
    load_ms: Option<f64>,
    /// The first encode, which compiles the encode's pipelines, ms (the timed encodes come after it).
    first_encode_ms: f64,
    encode: (Stats, Option<Stats>),
    pub(super) encoded: EncodedScene<'a>,
    references: std::result::Result<&'a References, String>,
}

impl Bench {
    /// A render's wall time and, with timestamps, its GPU time.
    fn render_sample(&self, encoded: &EncodedScene, targets: &TargetViews, request: Request) -> Result<Sample> {
        let start = Instant::now();
        encoded.render(targets, request)?;
        let wall = start.elapsed();
        Ok(Sample { wall, gpu: self.gpu.take_timestamps()?.map(|t| t.total) })
    }

    /// Encodes `inputs` once (the first encode, timed apart: it compiles), then repeatedly; returns the first
    /// encode's wall time (ms), the timings and the last encoded scene.
    fn encode<'m>(
        &self,
        model: &'m Model,
        inputs: &InputViews,
    ) -> Result<(f64, (Stats, Option<Stats>), EncodedScene<'m>)> {
        let start = Instant::now();
        let mut last = Some(model.encode(inputs)?);
        let first_ms = start.elapsed().as_secs_f64() * 1e3;
        self.gpu.take_timestamps()?;
        let stats = measure::repeat(Repeats { warmup: 0, ..self.repeats }, || -> Result<Sample> {
            let start = Instant::now();
            let encoded = model.encode(inputs)?;
            let wall = start.elapsed();
            let gpu = self.gpu.take_timestamps()?.map(|t| t.total);
            last = Some(encoded);
            Ok(Sample { wall, gpu })
        })?;
        Ok((first_ms, stats, last.expect("at least one encode")))
    }

    /// Both float64 references of a model and their encodings, when affordable: the encode's multiply-adds,
    /// counted from the ops `model`'s encode records (nothing is built), at most the limit. Else why not: too
    /// slow, or (for a family other than SRT, whose reference is required) the reference's own refusal.
    pub(super) fn references(
        &self,
        loaded: &LoadedModel,
        model: &Model,
        inputs: &InputViews,
    ) -> Result<MaybeReferences> {
        if model.encode_multiply_adds(inputs.count, inputs.height, inputs.width) > self.reference_macs {
            return Ok(Err("too slow at this size".into()));
        }
        let f64_args = match ReferenceModel::new(loaded, Argument::Float64) {
            Ok(reference) => reference,
            Err(e) if loaded.config.srt().is_none() => return Ok(Err(e.to_string())),
            Err(e) => return Err(e.into()),
        };
        // The accuracy run compares with the float64 model only (the encode of the largest models takes minutes).
        let rounded = if self.accuracy {
            None
        } else {
            let f32_args = ReferenceModel::new(loaded, Argument::RoundedToF32)?;
            let scene = f32_args.encode(inputs)?;
            Some((f32_args, scene))
        };
        let exact = f64_args.encode(inputs)?;
        Ok(Ok(References { rounded, exact: (f64_args, exact), renders: Mutex::new(Vec::new()) }))
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn subject<'a>(
        &self,
        name: String,
        group: &'static str,
        loaded: &'a LoadedModel,
        file: Option<&'a [u8]>,
        model: &'a Model,
        (precision, load_ms): (Precision, Option<f64>),
        inputs: &'a InputViews,
        references: std::result::Result<&'a References, String>,
    ) -> Result<Subject<'a>> {
        let (first_encode_ms, encode, encoded) = self.encode(model, inputs)?;
        Ok(Subject {
            name,
            group,
            loaded,
            file,
            model,
            precision,
            inputs,
            load_ms,
            first_encode_ms,
            encode,
            encoded,
            references,
        })
    }

    /// The fields of a record that do not need a render: the configuration, the encode's FLOPs, the memory a
    /// materialised softmax would take. The render's FLOPs come from its plan (or a prediction) later.
    pub(super) fn record(&self, s: &Subject, views: usize, size: (usize, usize), variant: &str) -> Record {
        let cfg = &s.loaded.config;
        let k = cfg.patch_size();
        // The latent's rows: SRT's tokens, OSRT's slots.
        let tokens = s.encoded.latent.rows;
        let queries = views * (size.0 / k) * (size.1 / k);
        let attention_scores_bytes = (cfg.describe().decoder_attention_heads().into_iter())
            .map(|heads| flops::attention_score_bytes(queries, tokens, heads))
            .sum();
        Record {
            group: s.group.to_string(),
            model: s.name.clone(),
            decoder: cfg.name(),
            k,
            precision: s.precision.name().into(),
            kernel: format!("{:?}", s.model.kernel_family()),
            variant: variant.to_string(),
            parameters: s.loaded.parameter_count(),
            weight_bytes: s.model.weight_bytes(),
            input_views: s.inputs.count,
            input_size: size_text((s.inputs.height, s.inputs.width)),
            target_views: views,
            target_size: size_text(size),
            pixels: views * size.0 * size.1,
            queries,
            tokens,
            timing: self.timing().into(),
            encode_ms: s.encode.1.or(Some(s.encode.0)),
            encode_wall_ms: Some(s.encode.0),
            load_wall_ms: s.load_ms,
            first_encode_wall_ms: Some(s.first_encode_ms),
            encode_peak_bytes: Some(s.encoded.encode_peak_bytes),
            attention_scores_bytes,
            encode_gflop: flops::gflop(s.encoded.encode_multiply_adds),
            env: Some(self.env.clone()),
            ..Default::default()
        }
    }

    /// Renders once (building the plan), then times repeated renders; fills the record's timing, memory and
    /// work fields and returns the first frame.
    pub(super) fn time_render(
        &self,
        s: &Subject,
        targets: &TargetViews,
        request: Request,
        record: &mut Record,
    ) -> Result<Frame> {
        let compiled = self.gpu.counters().pipelines_compiled;
        let start = Instant::now();
        let frame = s.encoded.render(targets, request)?;
        record.first_render_wall_ms = Some(start.elapsed().as_secs_f64() * 1e3);
        record.first_render_pipelines = Some(self.gpu.counters().pipelines_compiled - compiled);
        self.gpu.take_timestamps()?;
        let stats = s.encoded.render_stats(targets, request)?;
        (record.render_peak_bytes, record.dispatches, record.queries) =
            (Some(stats.peak_bytes), Some(stats.dispatches), stats.queries);
        record.render_staging_bytes = Some(stats.staging_bytes);
        record.render_gflop = flops::gflop(stats.multiply_adds);
        // The first render was the warm-up (it built the plan): what later renders allocate is counted.
        let repeats = Repeats { warmup: 0, ..self.repeats };
        let before = self.gpu.counters();
        let (wall, mut gpu) = measure::repeat(repeats, || self.render_sample(&s.encoded, targets, request))?;
        let after = self.gpu.counters();
        let runs = wall.runs as f64;
        record.render_buffers_per_run = Some((after.buffers_created - before.buffers_created) as f64 / runs);
        record.render_bytes_per_run = Some((after.bytes_allocated - before.bytes_allocated) as f64 / runs);
        if stats.bands > 1 {
            // Timestamps cover the last band's plan only: time the whole banded render by the wall clock.
            gpu = None;
            record.note = format!("{} row bands (largest buffer over the adapter's limit), wall clock", stats.bands);
        }
        set_times(record, wall, gpu);
        Ok(frame)
    }

    /// Measures one render configuration of a subject. `truth`: PyTorch's rgb for these targets, if known.
    pub(super) fn measure(
        &self,
        s: &Subject,
        targets: &TargetViews,
        truth: Option<&[f32]>,
        with_torch: bool,
    ) -> Result<Record> {
        let grid = targets.grid_for(&s.loaded.config, "target views")?;
        let mut record = self.record(s, targets.count, (grid.height, grid.width), "");
        let mut frame = self.time_render(s, targets, model_outputs(&s.loaded.config).into(), &mut record)?;
        let rgb = frame.take(Output::Rgb).context("a default render has rgb")?;
        let render_macs = (record.render_gflop / 2.0 * 1e9) as u64;
        let mut reference = None;
        let no_reference = match &s.references {
            Ok(references) if render_macs <= self.reference_macs => {
                let render = references.render(targets)?;
                if let Some(want) = &render.rounded {
                    record.max_err_f64_reference = Some(measure::max_abs_error(&rgb, &want.rgb));
                    record.rms_err_f64_reference = Some(measure::rms_error(&rgb, &want.rgb));
                }
                record.max_err_f64_model = Some(measure::max_abs_error(&rgb, &render.exact.rgb));
                // The other outputs against the float64 model: from the timed frame where it has them, else
                // from a render of them alone (the timed request is what the official forward returns).
                let others = other_outputs(s.model.outputs());
                let missing: Vec<Output> = others.iter().copied().filter(|&o| frame.get(o).is_none()).collect();
                let extra =
                    if missing.is_empty() { None } else { Some(s.encoded.render(targets, Outputs::of(&missing))?) };
                let get = |o: Output| frame.get(o).or_else(|| extra.as_ref().and_then(|e| e.get(o)));
                record.max_err_logdepth_f64_model = compare(get(Output::LogDepth), render.exact.logdepth.as_deref());
                record.max_err_segmentation_f64_model =
                    compare(get(Output::Segmentation), render.exact.segmentation.as_deref());
                reference = Some(render);
                None
            }
            Ok(_) => Some("too slow at this size"),
            Err(why) => Some(why.as_str()),
        };
        if let Some(why) = no_reference {
            record.note = format!("{}; no f64 reference ({why})", record.note).trim_start_matches("; ").into();
        }
        if let Some(truth) = truth {
            record.max_err_pytorch = Some(max_abs_f32(&rgb, truth));
        }
        if let Some(images) = &targets.images {
            record.psnr_db = Some(measure::psnr(&rgb, images, targets.count));
        }
        if with_torch {
            // PyTorch failing (e.g. out of memory at a large size) is reported in the record, not fatal.
            let exact = reference.as_ref().map(|r| &r.exact);
            if let Err(e) = self.time_pytorch(s, targets, &rgb, exact, &mut record) {
                record.note = format!("{} PyTorch failed: {e:#}", record.note).trim().to_string();
            }
        }
        report::progress::print_row(&record);
        Ok(record)
    }

    fn time_pytorch(
        &self,
        s: &Subject,
        targets: &TargetViews,
        rgb: &[f32],
        exact: Option<&ReferenceFrame>,
        record: &mut Record,
    ) -> Result<()> {
        let (Ok(torch), Some(file)) = (&self.torch, s.file) else {
            return Ok(());
        };
        // Model-file subjects are named by their path: keep the scratch file name flat.
        let flat: String = s.name.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
        let model_path = self.scratch.join(format!("{flat}-k{}.safetensors", record.k));
        if !model_path.exists() {
            report::write_file(&model_path, file)?;
        }
        let scene_path = self.scratch.join(format!("scene-{}.safetensors", record.target_size));
        report::write_file(&scene_path, &synthetic::scene_file(s.inputs, targets).map_err(anyhow::Error::msg)?)?;
        // A GPU renders in milliseconds: more runs there for a stable median.
        let repeats = match (self.quick, torch.device) {
            (true, _) => 1,
            (false, pytorch::Device::Cpu) => 3,
            (false, pytorch::Device::Cuda) => 20,
        };
        let repeats = if self.accuracy { 1 } else { repeats };
        let run = pytorch::run(torch, &model_path, &scene_path, repeats)?;
        record.max_err_pytorch = Some(max_abs_f32(rgb, &run.outputs.rgb));
        if let Some(exact) = exact {
            record.max_err_pytorch_f64_model = compare(Some(&run.outputs.rgb), Some(&exact.rgb));
            if let Some((_, autocast)) = &run.autocast {
                record.max_err_autocast_f64_model = compare(Some(&autocast.rgb), Some(&exact.rgb));
                record.max_err_autocast_logdepth_f64_model =
                    compare(autocast.logdepth.as_deref(), exact.logdepth.as_deref());
                record.max_err_autocast_segmentation_f64_model =
                    compare(autocast.segmentation.as_deref(), exact.segmentation.as_deref());
            }
        }
        if let Some((phases, _)) = &run.autocast {
            (record.pytorch_autocast_encode_ms, record.pytorch_autocast_render_ms) =
                (Some(phases.encode), Some(phases.render));
        }
        record.pytorch_over_ours = record.render_wall_ms.map(|ours| run.eager.render.median_ms / ours.median_ms);
        let on = match torch.device {
            pytorch::Device::Cpu => match &run.cpu_capability {
                Some(isa) => format!("{} CPU threads ({isa})", run.threads),
                None => format!("{} CPU threads", run.threads),
            },
            pytorch::Device::Cuda => torch.device_name.clone(),
        };
        record.note = format!("{} PyTorch on {on}", record.note).trim().to_string();
        (record.pytorch_encode_ms, record.pytorch_render_ms) = (Some(run.eager.encode), Some(run.eager.render));
        match run.compiled {
            Ok(compiled) => {
                record.pytorch_compiled_encode_ms = compiled.map(|c| c.encode);
                record.pytorch_compiled_render_ms = compiled.map(|c| c.render);
            }
            Err(why) => record.note += &format!("; torch.compile failed: {why}"),
        }
        Ok(())
    }
}

/// Fills the render timing fields: GPU time when there is one, else wall time.
pub(super) fn set_times(record: &mut Record, wall: Stats, gpu: Option<Stats>) {
    record.render_gpu_ms = gpu;
    let render = gpu.unwrap_or(wall);
    record.render_ms = Some(render);
    record.render_wall_ms = Some(wall);
    record.fps = Some(1e3 * record.target_views as f64 / render.median_ms);
}

/// max |a − b| of an output both sides have, of the same size; `None` where either lacks it (or they differ
/// in size: not the same output).
fn compare(a: Option<&[f32]>, b: Option<&[f64]>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) if a.len() == b.len() && !a.is_empty() => Some(measure::max_abs_error(a, b)),
        _ => None,
    }
}

/// The outputs beside rgb compared with the float64 model, of those `outputs` a model has: log-depth and
/// OSRT's segmentation.
fn other_outputs(outputs: Outputs) -> Vec<Output> {
    [Output::LogDepth, Output::Segmentation].into_iter().filter(|&o| outputs.contains(o)).collect()
}

fn max_abs_f32(a: &[f32], b: &[f32]) -> f64 {
    let b: Vec<f64> = b.iter().map(|&v| v as f64).collect();
    measure::max_abs_error(a, &b)
}

/// What a measured render computes: what the official model's forward returns (rgb, and DeFiNe's log-depth,
/// which needs its second head).
pub(super) fn model_outputs(config: &ModelConfig) -> Outputs {
    if config.describe().depth_has_own_head() {
        Outputs::of(&[Output::Rgb, Output::LogDepth])
    } else {
        Outputs::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_compared_only_where_both_sides_have_them() {
        assert_eq!(compare(Some(&[0.5, 1.0]), Some(&[0.25, 1.0])), Some(0.25));
        assert_eq!(compare(None, Some(&[0.25])), None);
        assert_eq!(compare(Some(&[0.5]), None), None);
        assert_eq!(compare(Some(&[0.5, 1.0]), Some(&[0.25])), None);
        assert_eq!(compare(Some(&[]), Some(&[])), None);
        assert_eq!(compare(Some(&[f32::NAN]), Some(&[0.0])), Some(f64::INFINITY));
    }

    #[test]
    fn the_other_outputs_are_log_depth_and_segmentation() {
        let osrt = Outputs::of(&[Output::Rgb, Output::Segmentation]);
        assert_eq!(other_outputs(osrt), [Output::Segmentation]);
        let define = Outputs::of(&[Output::Rgb, Output::LogDepth, Output::Depth]);
        assert_eq!(other_outputs(define), [Output::LogDepth]);
        assert!(other_outputs(Outputs::of(&[Output::Rgb])).is_empty());
    }
}
