//! Rendering the shots and streaming each frame to its outputs as it comes (a video's frames are never all
//! held), with a progress bar on a terminal; nothing is moved into place until every frame was written.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use raypatch::{Camera, Image, Output, Outputs, Rendered, Request, Scene};

use crate::cameras::Shot;
use crate::files::{raw_bytes, Destinations, OutDest};
use crate::panels::{frame_picture, widen_range, Panel};
use crate::video::{FrameWriter, Mp4Mode};

/// Frames a sequence renders per render call (one plan of this many target views): fewer submits and
/// readbacks, and on GPUs fuller dispatches; few enough that the first frames come soon.
const SEQUENCE_BATCH: usize = 4;

pub struct Sequence<'a> {
    pub shots: &'a [Shot],
    pub request: Request,
    pub panels: &'a [Panel],
    /// --depth-range: the range of every depth picture and panel.
    pub depth_range: Option<(f32, f32)>,
    /// The first input view, for the input panel.
    pub input: &'a Image,
    pub fps: f64,
    /// How an MP4 is encoded.
    pub mp4: Mp4Mode,
    /// Show a progress bar (on a terminal only).
    pub progress: bool,
    /// Keep every frame's outputs (for --metrics and --out-raw).
    pub keep: bool,
    /// Whether the shots are a sequence (a path, a motion, a turntable): with a progress bar, and
    /// [`SEQUENCE_BATCH`] frames per render call (views of one size go as many at once as fit the engine's
    /// memory budget).
    pub batched: bool,
}

/// What [`Sequence::render`] did: the frames' outputs when kept, timings, and the written outputs, still
/// temporaries until [`Staged::commit`](raypatch::Staged::commit).
pub struct Rendering {
    pub kept: Vec<Rendered>,
    pub frames: usize,
    pub region: raypatch::Region,
    /// The first render call, which builds the plan (buffers allocated, pipelines compiled).
    pub first: Duration,
    pub total: Duration,
    /// Each render's time, when frames are rendered one per call.
    pub each: Vec<Duration>,
    /// Frames per render call.
    pub batch: usize,
    pub writing: raypatch::Staged,
}

impl Sequence<'_> {
    /// Frames per render call: [`SEQUENCE_BATCH`] for a sequence; target views of one size as many as the
    /// engine's memory budget allows (`Scene::views_per_batch`), each still its own frame.
    pub fn batch(&self, scene: &Scene) -> Result<usize> {
        if self.batched {
            return Ok(SEQUENCE_BATCH);
        }
        let size = |c: &Camera| (c.width(), c.height(), c.pixels_per_ray());
        let first = &self.shots[0].camera;
        if self.shots.len() == 1 || self.shots.iter().any(|s| size(&s.camera) != size(first)) {
            return Ok(1);
        }
        Ok(scene.views_per_batch(first, &self.request, self.shots.len())?)
    }

    fn progress_bar(&self, what: &str) -> ProgressBar {
        if !self.progress || !self.batched {
            return ProgressBar::hidden();
        }
        // indicatif draws nothing when stderr is not a terminal.
        let bar = ProgressBar::with_draw_target(Some(self.shots.len() as u64), ProgressDrawTarget::stderr());
        let template = format!("{what} {{bar:40}} {{pos}}/{{len}} frames, {{per_sec}}, {{elapsed}} (eta {{eta}})");
        bar.set_style(ProgressStyle::with_template(&template).expect("a valid template"));
        bar
    }

    /// The one depth range of the depth panels: --depth-range, else a first pass rendering only the depth of
    /// every frame (no colour is decoded, nothing is kept but the running minimum and maximum).
    fn panel_depth_range(&self, scene: &Scene, cameras: &[Camera], batch: usize) -> Result<Option<(f32, f32)>> {
        if !self.panels.contains(&Panel::Depth) || self.depth_range.is_some() {
            return Ok(self.depth_range);
        }
        let request = Request { outputs: Outputs::NONE.with(Output::Depth), ..self.request };
        let bar = self.progress_bar("depth range");
        let mut range = None;
        for (i, frame) in scene.render_path(cameras, &request, batch).enumerate() {
            let frame = frame.with_context(|| self.shots[i].label.clone())?;
            range = widen_range(range, frame.depth().expect("depth was requested"));
            bar.inc(1);
        }
        bar.finish_and_clear();
        let (lo, hi) = range.context("--panels depth: no pixel of any frame has a depth to set the colour range")?;
        // One depth everywhere: a range around it, so that the colour bar still reads.
        Ok(Some(if hi > lo { (lo, hi) } else { (lo * 0.99, hi * 1.01 + f32::EPSILON) }))
    }

    /// Renders every shot, writing each frame's outputs as it comes.
    pub fn render(&self, scene: &Scene, destinations: &Destinations) -> Result<Rendering> {
        let cameras: Vec<Camera> = self.shots.iter().map(|s| s.camera.clone()).collect();
        let batch = self.batch(scene)?;
        let panel_range = self.panel_depth_range(scene, &cameras, batch)?;
        let mut writing = destinations.files.begin()?;
        let mut writer = match &destinations.out {
            Some(OutDest::Video(path, format)) => {
                Some(FrameWriter::video(&mut writing, *format, path, self.fps, self.mp4)?)
            }
            Some(OutDest::Pngs(paths)) => Some(FrameWriter::Pngs { paths: paths.clone(), next: 0 }),
            None => None,
        };
        let bar = self.progress_bar("rendering");
        let (mut kept, mut each, mut region) = (Vec::new(), Vec::new(), None);
        let start = Instant::now();
        let mut first = Duration::ZERO;
        let mut frames = scene.render_path(&cameras, &self.request, batch);
        let mut i = 0;
        loop {
            let call = Instant::now();
            let Some(frame) = frames.next() else { break };
            let frame = frame.with_context(|| self.shots[i].label.clone())?;
            if i == 0 {
                first = call.elapsed();
            }
            each.push(call.elapsed());
            region.get_or_insert(frame.region);
            if let Some(writer) = &mut writer {
                let picture = frame_picture(self.panels, &frame, panel_range, self.input)?;
                writer.push(&mut writing, &picture).with_context(|| self.shots[i].label.clone())?;
            }
            if let Some(path) = destinations.segmentation.get(i) {
                let (weights, slots) = frame.segmentation().expect("segmentation was requested");
                let picture = Image::from_segmentation(frame.region.width, frame.region.height, weights, slots)?;
                writing.create(path)?.write_all(&picture.encode_png()?)?;
            }
            if let Some(path) = destinations.depth.get(i) {
                let depth = frame.depth().expect("depth was requested");
                let picture = Image::from_depth(frame.region.width, frame.region.height, depth, self.depth_range)?;
                writing.create(path)?.write_all(&picture.encode_png()?)?;
            }
            if self.keep {
                kept.push(frame);
            }
            bar.inc(1);
            i += 1;
        }
        let total = start.elapsed();
        bar.finish_and_clear();
        if let Some(writer) = writer {
            writer.finish().with_context(|| format!("--out {}", destinations.out_path().display()))?;
        }
        if let Some(path) = &destinations.raw {
            writing.create(path)?.write_all(&raw_bytes(&kept)?)?;
        }
        if batch > 1 {
            each.clear();
        }
        Ok(Rendering {
            kept,
            frames: i,
            region: region.expect("at least one shot"),
            first,
            total,
            each,
            batch,
            writing,
        })
    }
}
