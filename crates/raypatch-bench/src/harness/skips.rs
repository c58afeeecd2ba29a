//! The measurements of what the API skips, on and off: outputs not asked for (log-depth, segmentation), the plan cache,
//! the per-scene encoding and a region of interest; and the per-op, per-kernel breakdown of a render's GPU
//! time (timestamps between the ops).

use std::time::Instant;

use anyhow::{bail, Result};
use raypatch_engine::gpu::{GpuTimes, TimestampMode};
use raypatch_engine::{Output, Outputs, Region, Request};
use raypatch_model::TargetViews;

use super::measurement::{model_outputs, set_times, Subject};
use super::Bench;
use crate::flops;
use crate::measure::{self, Sample, Stats};
use crate::report::progress::print_row;
use crate::report::{KernelTime, Record};

impl Bench {
    /// Outputs not asked for are not computed: rgb only, rgb and log-depth, log-depth only.
    pub(super) fn logdepth_skip(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<Record>> {
        self.outputs_skip(s, targets, Output::LogDepth)
    }

    /// What OSRT's segmentation (the mixing weights, per pixel) costs: rgb only, rgb and segmentation,
    /// segmentation only (no slot mix, render MLP or Ray-Patch convolutions).
    pub(super) fn segmentation_skip(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<Record>> {
        self.outputs_skip(s, targets, Output::Segmentation)
    }

    /// Renders of rgb, rgb and `other`, `other` alone (render time, planned memory and work of each).
    fn outputs_skip(&self, s: &Subject, targets: &TargetViews, other: Output) -> Result<Vec<Record>> {
        let grid = targets.grid_for(&s.loaded.config, "target views")?;
        let mut rows = Vec::new();
        let name = other.title();
        let variants = [
            ("outputs: rgb".to_string(), Outputs::of(&[Output::Rgb])),
            (format!("outputs: rgb + {name}"), Outputs::of(&[Output::Rgb, other])),
            (format!("outputs: {name}"), Outputs::of(&[other])),
        ];
        for (variant, outputs) in variants {
            let mut record = self.record(s, targets.count, (grid.height, grid.width), &variant);
            record.group = "skips".into();
            self.time_render(s, targets, outputs.into(), &mut record)?;
            print_row(&record);
            rows.push(record);
        }
        Ok(rows)
    }

    /// The skips of the API, on and off: the plan cache, the per-scene encoding, and a region of interest.
    pub(super) fn plan_and_encode_skips(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<Record>> {
        let full = Request::from(Outputs::default());
        let grid = targets.grid_for(&s.loaded.config, "target views")?;
        let size = (grid.height, grid.width);
        let row = |variant: &str, wall: Stats, request: Request| -> Result<Record> {
            let mut record = self.record(s, targets.count, size, variant);
            record.group = "skips".into();
            record.timing = "wall clock".into();
            set_times(&mut record, wall, None);
            let stats = s.encoded.render_stats(targets, request)?;
            (record.render_peak_bytes, record.dispatches, record.queries) =
                (Some(stats.peak_bytes), Some(stats.dispatches), stats.queries);
            record.render_gflop = flops::gflop(stats.multiply_adds);
            print_row(&record);
            Ok(record)
        };
        let wall = |f: &dyn Fn() -> Result<()>| {
            measure::repeat(self.repeats, || -> Result<Sample> {
                let start = Instant::now();
                f()?;
                self.gpu.take_timestamps()?;
                Ok(Sample { wall: start.elapsed(), gpu: None })
            })
            .map(|(wall, _)| wall)
        };
        let cached = wall(&|| s.encoded.render(targets, full).map(drop).map_err(Into::into))?;
        // Without the plan cache every render builds its plan (buffers, params, bind groups) first.
        let rebuilt = wall(&|| {
            s.encoded.clear_render_plans();
            s.encoded.render(targets, full)?;
            Ok(())
        })?;
        let build = wall(&|| {
            s.encoded.clear_render_plans();
            s.encoded.render_stats(targets, full)?;
            Ok(())
        })?;
        // Without the per-scene encoding every render encodes the input views (latent, keys, values) again.
        let encode_each = wall(&|| {
            let encoded = s.model.encode(s.inputs)?;
            self.gpu.take_timestamps()?;
            encoded.render(targets, full)?;
            Ok(())
        })?;
        // A region of interest: the top-left quarter of the image; only the patches it needs are decoded.
        let quarter = Request { region: Some(Region { x: 0, y: 0, width: size.1 / 2, height: size.0 / 2 }), ..full };
        s.encoded.render(targets, quarter)?;
        let region = wall(&|| s.encoded.render(targets, quarter).map(drop).map_err(Into::into))?;
        Ok(vec![
            row("plan cached, scene encoded once", cached, full)?,
            row("plan rebuilt per render", rebuilt, full)?,
            Record { fps: None, ..row("(plan build alone)", build, full)? },
            row("scene encoded per render", encode_each, full)?,
            row("region: top-left quarter", region, quarter)?,
        ])
    }

    /// One encode and one render with a timestamp between every two ops, summed per op (layer indices and
    /// query chunks folded) and per kernel.
    pub(super) fn kernel_breakdown(&self, s: &Subject, targets: &TargetViews) -> Result<Vec<KernelTime>> {
        if self.gpu.set_timestamps(TimestampMode::Ops).is_err() {
            return Ok(Vec::new());
        }
        let times = (|| -> Result<(Option<GpuTimes>, Option<GpuTimes>)> {
            s.model.encode(s.inputs)?;
            let encode = self.gpu.take_timestamps()?;
            s.encoded.render(targets, model_outputs(&s.loaded.config))?;
            Ok((encode, self.gpu.take_timestamps()?))
        })();
        self.gpu.set_timestamps(TimestampMode::Plan)?;
        let (Some(encode), Some(render)) = times? else { bail!("no timestamps came back") };
        let k = s.loaded.config.patch_size();
        let grid = targets.grid_for(&s.loaded.config, "target views")?;
        let config = format!(
            "{} {} k={k} {}x{} {}",
            s.name,
            &s.loaded.config.name(),
            grid.height,
            grid.width,
            s.precision.name()
        );
        let mut rows = crate::kernels::fold(&format!("{config} render"), &render);
        rows.extend(crate::kernels::fold(&format!("{config} encode"), &encode));
        Ok(rows)
    }
}
