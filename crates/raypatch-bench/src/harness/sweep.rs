//! The sweep of random-weight models (small and official size, SRT and RP-SRT k ∈ {2, 4, 8, 16}, f32 and f16
//! weights; the official OSRT and RP-OSRT k=8 at their 120x160, and DeFiNe and RP-DeFiNe k=16 at 480x640 and
//! 960x1280 from two 128x192 views, f32) over target sizes, with the skip of sizes
//! predicted too slow: a size's render is predicted from the multiply-adds its plan would record (recorded,
//! not built) and the rate measured at the previous size.

use std::time::Instant;

use anyhow::Result;
use raypatch_engine::encoded::BATCH_BUDGET_BYTES;
use raypatch_engine::{EngineError, LoadOptions, MatmulKernel, Model, Precision, Request};
use raypatch_model::TargetViews;

use super::measurement::{model_outputs, set_times, Subject};
use super::{
    scene, size_text, Bench, Checkpoint, Size, FULL_SIZES, INPUT_SIZE, PATCH_SIZES, QUICK_SIZES, SEED, SMALL_WIDTH,
};
use crate::measure::{self, Repeats, Sample};
use crate::report::{self, KernelTime, Record};
use crate::synthetic;
use crate::{flops, pytorch};

/// The group of the official OSRT runs: `osrt_MDBN_64` (k = 1) and `rposrt_MDBN_8_64` (k = 8).
pub(crate) const OSRT: &str = "official-osrt";
/// The group of the official ScanNet DeFiNe runs: `define_32_stereo_acc` (k = 1) and
/// `rpdefine_16_32_stereo_acc` (k = 16).
pub(crate) const DEFINE: &str = "official-define";
/// DeFiNe's official stereo setting: two input views of 128x192, targets of 480x640, and the sizes around it
/// up to the paper's Figure 2's 960x1280 (the smaller ones predict the larger renders' time).
const DEFINE_INPUTS: (usize, Size) = (2, (128, 192));
const DEFINE_SIZES: [Size; 4] = [(120, 160), (240, 320), (480, 640), (960, 1280)];
/// The accuracy run's models (`--accuracy`): each official family at a target size whose float64 render takes
/// seconds on 2 cores (the per-pixel decoders at 24x32, the Ray-Patch ones at a size of their official k's
/// whole patches: RP-SRT and RP-OSRT k=8 at 120x160, RP-DeFiNe k=16 at 240x320), as (group, k, size).
pub(crate) const ACCURACY: [(&str, usize, Size); 6] = [
    ("official", 1, (24, 32)),
    ("official", 8, (120, 160)),
    (OSRT, 1, (24, 32)),
    (OSRT, 8, (120, 160)),
    (DEFINE, 1, (24, 32)),
    (DEFINE, 16, (240, 320)),
];

/// One model of the sweep: its group, k and config, its input views (count, size) and its target sizes.
struct Spec<'a> {
    name: &'a str,
    k: usize,
    config: serde_json::Value,
    inputs: (usize, Size),
    sizes: &'a [Size],
}

impl Bench {
    /// Random-weight models: small and official size, SRT and RP-SRT k ∈ {2, 4, 8, 16}, over target sizes; the
    /// official OSRT (`osrt_MDBN_64`) and RP-OSRT k=8 (`rposrt_MDBN_8_64`) at the official 120x160 (not in the
    /// quick run unless asked for with `--only official-osrt:K`: an OSRT render is minutes on lavapipe).
    /// Measures every model of the sweep (those `--only` names), calling `checkpoint` with the records so far
    /// after each size.
    pub(super) fn sweep(
        &self,
        records: &mut Vec<Record>,
        kernels: &mut Vec<KernelTime>,
        checkpoint: &mut Checkpoint,
    ) -> Result<()> {
        let (small_sizes, official): (&[Size], Vec<(usize, &[Size])>) = if self.quick {
            (&QUICK_SIZES, vec![(8, &[(120, 160)])])
        } else {
            (&FULL_SIZES, PATCH_SIZES.iter().map(|&k| (k, &FULL_SIZES[..])).collect())
        };
        let spec = |name, k, config, sizes| Spec { name, k, config, inputs: (1, INPUT_SIZE), sizes };
        let mut specs: Vec<Spec> = PATCH_SIZES
            .iter()
            .map(|&k| spec("small", k, synthetic::small_config(k, SMALL_WIDTH), small_sizes))
            .collect();
        for (k, sizes) in official {
            let config = if k == 1 { synthetic::official_srt_config() } else { synthetic::official_rpsrt_config(k) };
            specs.push(spec("official", k, config, sizes));
        }
        if self.accuracy {
            specs = ACCURACY
                .iter()
                .map(|(name, k, size)| {
                    let config = match *name {
                        "official" if *k == 1 => synthetic::official_srt_config(),
                        "official" => synthetic::official_rpsrt_config(*k),
                        OSRT if *k == 1 => synthetic::official_osrt_config(),
                        OSRT => synthetic::official_rposrt_config(),
                        _ => synthetic::official_define_config(*k),
                    };
                    let inputs = if *name == DEFINE { DEFINE_INPUTS } else { (1, INPUT_SIZE) };
                    Spec { name, k: *k, config, inputs, sizes: std::slice::from_ref(size) }
                })
                .collect();
        } else if !self.quick || !self.only.is_empty() {
            specs.push(spec(OSRT, 1, synthetic::official_osrt_config(), &[(120, 160)]));
            specs.push(spec(OSRT, 8, synthetic::official_rposrt_config(), &[(120, 160)]));
            for k in [1, 16] {
                let config = synthetic::official_define_config(k);
                specs.push(Spec { inputs: DEFINE_INPUTS, ..spec(DEFINE, k, config, &DEFINE_SIZES) });
            }
        }
        println!(
            "random-weight models, 1 input view {}x{} (DeFiNe: 2 views of 128x192), 1 target view",
            INPUT_SIZE.0, INPUT_SIZE.1
        );
        let f16 = self.gpu.features.contains(raypatch_engine::wgpu::Features::SHADER_F16);
        if !self.only.is_empty() {
            specs.retain(|s| self.only.iter().any(|(n, only_k)| n == s.name && *only_k == s.k));
        }
        for Spec { name, k, config, inputs: (views, input_size), sizes } in specs {
            let (loaded, file) = synthetic::random_model(&config, SEED + k as u64, name)?;
            let (inputs, _) = scene(views, input_size, 1, input_size)?;
            // Whether the float64 references are affordable is decided from the first model's encode (the
            // precision does not change the work), and they serve every precision.
            let mut references = None;
            let mut precisions = vec![Precision::F32];
            // OSRT and DeFiNe in f32 only (the paper's comparison; f16 weights scale as they do for SRT). f16
            // activations only where linear layers run on `Tiled` (GPUs): elsewhere they compute as f16 weights.
            if f16 && (name == "small" || !self.quick) && name != OSRT && name != DEFINE {
                precisions.push(Precision::F16Weights);
                if self.gpu.kernels.matmul == MatmulKernel::Tiled {
                    precisions.push(Precision::F16Activations);
                }
            }
            if !self.precisions.is_empty() {
                precisions = chosen_precisions(&self.precisions, f16);
                if precisions.len() < self.precisions.len() {
                    println!("  {name:<12} k={k:<2} f16 precisions not measured: the adapter has no shader-f16");
                }
            }
            let mut sizes: Vec<(usize, usize)> = sizes
                .iter()
                .filter(|s| s.0 % k == 0 && s.1 % k == 0 && (self.sizes.is_empty() || self.sizes.contains(s)))
                .copied()
                .collect();
            if sizes.is_empty() {
                println!("  {name:<12} k={k:<2} none of --sizes is among its sizes: not measured");
                continue;
            }
            for precision in precisions {
                // Loaded from its file's bytes, as `Engine::load_bytes` loads one: a first frame's load time.
                let start = Instant::now();
                let from_file = raypatch_model::weights::model_from_bytes(name, &file)?;
                let model = Model::from_loaded_with(self.gpu.clone(), &from_file, &LoadOptions { precision })?;
                let load_ms = start.elapsed().as_secs_f64() * 1e3;
                drop(from_file);
                if references.is_none() {
                    references = Some(self.references(&loaded, &model, &inputs)?);
                }
                let subject = self.subject(
                    name.to_string(),
                    "sweep",
                    &loaded,
                    Some(&file),
                    &model,
                    (precision, Some(load_ms)),
                    &inputs,
                    references.as_ref().expect("set above").as_ref().map_err(Clone::clone),
                )?;
                let measured = self.sweep_sizes(&subject, (views, input_size), &sizes, records, kernels, checkpoint)?;
                // f16 at the paper's sizes that f32 rendered: precision does not change how time scales with size
                // (with --precision, every size the first precision rendered).
                let f16_sizes: &[(usize, usize)] = if self.quick { &[(120, 160)] } else { &[(60, 80), (120, 160)] };
                let explicit = !self.precisions.is_empty();
                sizes = measured.into_iter().filter(|s| explicit || f16_sizes.contains(s)).collect();
            }
        }
        Ok(())
    }

    /// One subject over target sizes (ascending): sizes predicted to render slower than the limit are skipped.
    /// Calls `checkpoint` after each size measured. Returns the sizes rendered.
    fn sweep_sizes(
        &self,
        s: &Subject,
        (views, input_size): (usize, Size),
        sizes: &[(usize, usize)],
        records: &mut Vec<Record>,
        kernels: &mut Vec<KernelTime>,
        checkpoint: &mut Checkpoint,
    ) -> Result<Vec<(usize, usize)>> {
        let mut measured = Vec::new();
        let (name, k, f32_weights) = (s.name.as_str(), s.loaded.config.patch_size(), s.precision == Precision::F32);
        let mut rate: Option<f64> = None;
        for &size in sizes {
            let (_, targets) = scene(views, input_size, 1, size)?;
            // The render's multiply-adds, counted from the ops its plan would record (nothing is built).
            let macs = s.encoded.render_multiply_adds(&targets, model_outputs(&s.loaded.config))?;
            if let Some(rate) = rate {
                let predicted = macs as f64 / rate;
                if predicted > self.max_render.as_secs_f64() {
                    println!(
                        "  {name:<12} {:<7} k={k:<2} {:>9} skipped: predicted {predicted:.0} s per render",
                        &s.loaded.config.name(),
                        size_text(size)
                    );
                    records.push(self.skipped(s, &targets, predicted, macs)?);
                    continue;
                }
            }
            let with_torch = f32_weights && (self.accuracy || self.torch_config(name, k, size));
            let mut record = match self.measure(s, &targets, None, with_torch) {
                Ok(record) => record,
                // A plan needing a buffer beyond the adapter's binding limit is a result, not a failure.
                Err(e) if matches!(e.downcast_ref::<EngineError>(), Some(EngineError::TooLarge { .. })) => {
                    let decoder = &s.loaded.config.name();
                    println!("  {name:<12} {decoder:<7} k={k:<2} {:>9} does not fit: {e}", size_text(size));
                    let mut record = self.record(s, targets.count, size, "");
                    record.render_gflop = flops::gflop(macs);
                    record.note = format!("does not fit: {e}");
                    records.push(record);
                    s.encoded.clear_render_plans();
                    continue;
                }
                Err(e) => return Err(e),
            };
            if !s.model.weights_kept_f32().is_empty() {
                let kept: Vec<&str> = s.model.weights_kept_f32().iter().map(|k| k.tensor.as_str()).collect();
                record.note =
                    format!("{} kept in f32 (beyond f16 range): {}", record.note, kept.join(" ")).trim().to_string();
            }
            rate = record.render_wall_ms.map(|r| macs as f64 / (r.median_ms / 1e3));
            records.push(record);
            measured.push(size);
            // Many views at f32, and on the tensor path (issue 47's RP-SRT k=8 at 32 views, f16-act).
            if f32_weights || s.precision == Precision::F16Activations {
                records.extend(self.many_views(s, (views, input_size), size, macs, rate)?);
            }
            // The accuracy run measures errors: none of the time breakdowns and skips.
            let extras = f32_weights && !self.accuracy;
            if extras && self.breakdown_config(name, k, size) {
                kernels.extend(self.kernel_breakdown(s, &targets)?);
            }
            let skips = (name == "small" && k == 4) || (!self.quick && name == "official" && k == 8);
            if extras && skips && size == (120, 160) {
                records.extend(self.plan_and_encode_skips(s, &targets)?);
            }
            // What the segmentation costs beside rgb (RP-OSRT; OSRT's rgb render alone is minutes here).
            if extras && name == OSRT && k == 8 && size == (120, 160) {
                records.extend(self.segmentation_skip(s, &targets)?);
            }
            // Free this size's plan (its buffers) before the next, larger one.
            s.encoded.clear_render_plans();
            checkpoint(records, kernels)?;
        }
        Ok(measured)
    }

    /// Renders of `--views` target views at once at `size` (PyTorch rendering as many where it is timed at
    /// this size), each skipped where one view's multiply-adds `macs` at `rate` predict it too slow.
    fn many_views(
        &self,
        s: &Subject,
        (views, input_size): (usize, Size),
        size: Size,
        macs: u64,
        rate: Option<f64>,
    ) -> Result<Vec<Record>> {
        let (name, k) = (s.name.as_str(), s.loaded.config.patch_size());
        let mut records = Vec::new();
        for &count in &self.views {
            let (_, targets) = scene(views, input_size, count, size)?;
            let predicted = rate.map_or(0.0, |rate| (count as u64 * macs) as f64 / rate);
            if predicted > self.max_render.as_secs_f64() {
                records.push(self.skipped(s, &targets, predicted, count as u64 * macs)?);
                continue;
            }
            let with_torch = s.precision == Precision::F32 && self.torch_config(name, k, size);
            match self.measure(s, &targets, None, with_torch) {
                Ok(record) => {
                    records.push(record);
                    records.push(self.views_path(s, &targets)?);
                }
                Err(e) if matches!(e.downcast_ref::<EngineError>(), Some(EngineError::TooLarge { .. })) => {
                    let mut record = self.record(s, count, size, "");
                    record.note = format!("does not fit: {e}");
                    records.push(record);
                }
                Err(e) => return Err(e),
            }
            s.encoded.clear_render_plans();
        }
        Ok(records)
    }

    /// The views of `targets` as `render-frame --view all` renders them: a frame per view, in batches under
    /// the engine's memory budget, each submitted before the last is read back (its wall time beside the one
    /// batched call `measure` timed).
    fn views_path(&self, s: &Subject, targets: &TargetViews) -> Result<Record> {
        let grid = targets.grid_for(&s.loaded.config, "target views")?;
        let variant = "a frame per view, batched under the budget (render-frame --view all)";
        let mut record = self.record(s, targets.count, (grid.height, grid.width), variant);
        record.group = "views".into();
        let request = Request::from(model_outputs(&s.loaded.config));
        let fit = s.encoded.views_within(&targets.view(0), request, BATCH_BUDGET_BYTES)?;
        let batch = targets.count.div_ceil(targets.count.div_ceil(fit));
        let batches = || {
            (0..targets.count).step_by(batch).map(move |first| {
                let mut views = targets.view(first);
                for v in first + 1..(first + batch).min(targets.count) {
                    views.append(targets.view(v));
                }
                views
            })
        };
        let run = || -> Result<Sample> {
            let start = Instant::now();
            let frames: usize = s
                .encoded
                .render_sequence(batches(), request)
                .map(|f| f.map(|f| f.len()))
                .sum::<raypatch_engine::Result<usize>>()?;
            anyhow::ensure!(frames == targets.count, "{frames} frames of {} views", targets.count);
            Ok(Sample { wall: start.elapsed(), gpu: None })
        };
        let compiled = self.gpu.counters().pipelines_compiled;
        record.first_render_wall_ms = Some(run()?.wall.as_secs_f64() * 1e3);
        record.first_render_pipelines = Some(self.gpu.counters().pipelines_compiled - compiled);
        let (wall, _) = measure::repeat(Repeats { warmup: 0, ..self.repeats }, run)?;
        set_times(&mut record, wall, None);
        record.note = format!("{batch} views per render call");
        report::progress::print_row(&record);
        Ok(record)
    }

    fn torch_config(&self, name: &str, k: usize, size: (usize, usize)) -> bool {
        let on_cuda = self.torch.as_ref().is_ok_and(|t| t.device == pytorch::Device::Cuda);
        if on_cuda && !self.quick {
            // On a GPU PyTorch is fast, but torch.compile compiles each size: every model at 120x160 and 480x640.
            return size == (120, 160) || size == (480, 640);
        }
        match (self.quick, name) {
            (true, _) => k == 4 && size == (60, 80) && name == "small",
            (false, "small") => size == (120, 160) && (k == 1 || k == 4),
            (false, OSRT) => size == (120, 160),
            (false, DEFINE) => size == (480, 640),
            (false, _) => (size == (60, 80) && k <= 4) || (size == (120, 160) && k >= 4),
        }
    }

    fn breakdown_config(&self, name: &str, k: usize, size: (usize, usize)) -> bool {
        size == (120, 160) && ((name == "official" || name == OSRT) && (k == 1 || k == 8) || name == "small" && k == 4)
            || name == DEFINE && k == 16 && size == (480, 640)
    }

    /// A size not rendered: its FLOPs (`multiply_adds`, as predicted; the built plan's count when it fits)
    /// and planned memory (the plan is built, not run) with the prediction.
    fn skipped(&self, s: &Subject, targets: &TargetViews, predicted: f64, multiply_adds: u64) -> Result<Record> {
        let grid = targets.grid_for(&s.loaded.config, "target views")?;
        let mut record = self.record(s, targets.count, (grid.height, grid.width), "");
        record.render_gflop = flops::gflop(multiply_adds);
        record.note = format!("skipped: predicted {predicted:.0} s per render on this adapter");
        match s.encoded.render_stats(targets, model_outputs(&s.loaded.config)) {
            Ok(stats) => {
                (record.render_peak_bytes, record.dispatches) = (Some(stats.peak_bytes), Some(stats.dispatches));
                record.render_gflop = flops::gflop(stats.multiply_adds);
            }
            Err(e @ EngineError::TooLarge { .. }) => record.note += &format!("; does not fit: {e}"),
            Err(e) => return Err(e.into()),
        }
        s.encoded.clear_render_plans();
        Ok(record)
    }
}

/// The precisions `--precision` asked for that the adapter runs: the f16 ones only with shader-f16 (`f16`).
fn chosen_precisions(asked: &[Precision], f16: bool) -> Vec<Precision> {
    asked.iter().copied().filter(|&p| f16 || p == Precision::F32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn asked_precisions_need_shader_f16_for_f16() {
        let asked = [Precision::F32, Precision::F16Activations];
        assert_eq!(chosen_precisions(&asked, true), asked);
        assert_eq!(chosen_precisions(&asked, false), [Precision::F32]);
        assert!(chosen_precisions(&[Precision::F16Weights], false).is_empty());
    }

    #[test]
    fn the_accuracy_run_has_every_official_family_at_sizes_of_whole_patches() {
        let families: Vec<(&str, usize)> = ACCURACY.iter().map(|(name, k, _)| (*name, *k)).collect();
        assert_eq!(families, [("official", 1), ("official", 8), (OSRT, 1), (OSRT, 8), (DEFINE, 1), (DEFINE, 16)]);
        for (name, k, (h, w)) in ACCURACY {
            assert!(h % k == 0 && w % k == 0, "{name} k={k}: {h}x{w}");
        }
    }
}
