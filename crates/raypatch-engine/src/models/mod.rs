//! Model families. Each is one file that builds its module tree from `nn` modules and implements
//! [`LightField`]: what the scene core (`encoded.rs`) needs to encode a scene once and render any
//! crop of any target view. `ray_patch` is the Ray-Patch decoder every family can use.
//!
//! Adding a family: its config type in `raypatch-model/src/config/` (an arm of `Family`), its file here
//! (modules + `impl LightField`), an arm in [`build`]. Outputs it adds go in [`Output`].

pub mod define;
pub mod osrt;
pub mod ray_patch;
pub mod srt;

use std::ops::Range;

use raypatch_model::pinhole::TERM_FLOATS;
use raypatch_model::{Family, LoadedModel, ModelConfig, RaySource, TargetGrid};

use crate::error::Result;
use crate::frame::{Output, Outputs};
use crate::graph::{Graph, HostInput, ImageSize, Tensor};
use crate::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
use crate::kernels::rays::{pinhole_rays, PinholeRaysArgs};
use crate::kernels::resize::ResizeArgs;
use crate::nn::{self, ReadLimits, Source, Vars, WeightSet};
use crate::plan::PlanBuilder;
use crate::tensor::{padded_cols, GpuTensor};
use ray_patch::RayPatchDecoder;

/// A light-field model as the scene core uses it.
pub trait LightField: Send + Sync {
    /// The outputs this model can render.
    fn outputs(&self) -> Outputs;

    /// Pixels per decoder query along each axis: 1, or k for Ray-Patch.
    fn patch_size(&self) -> usize;

    /// The query patches `first..=last`, along an axis of `patches`, that output pixels `lo..=hi` depend on.
    fn patch_span(&self, lo: usize, hi: usize, patches: usize) -> (usize, usize);

    /// Checks that the encoder takes input views of `height`×`width` (a sentence naming what it needs).
    fn check_inputs(&self, _height: usize, _width: usize) -> std::result::Result<(), String> {
        Ok(())
    }

    /// Records the encoder on input views of `size`: the latent, and the tensors every render reads (plan
    /// outputs, kept with the scene).
    fn encode(&self, g: &mut Graph, size: ImageSize) -> Encoded;

    /// Records a render of `views` target views on `grid` (the computed crop), reading the scene's cached
    /// tensors, computing only `outputs`: each output as `[views·height·width, channels]`.
    fn render(
        &self,
        g: &mut Graph,
        scene: &[GpuTensor],
        views: usize,
        grid: TargetGrid,
        outputs: Outputs,
    ) -> Vec<(Output, Tensor)>;
}

/// What an encode plan produces.
pub struct Encoded {
    pub latent: Tensor,
    pub cached: Vec<Tensor>,
}

/// The module tree of a model file, with its weights on the host (checked against the file: every tensor
/// fetched, of its shape and within `limits`, nothing left over).
pub fn build(loaded: &LoadedModel, limits: ReadLimits) -> Result<(Box<dyn LightField>, WeightSet)> {
    build_from(&loaded.config, Source::File { model: loaded, limits })
}

/// Every tensor of the official state_dict for `config` (without `num_batches_tracked`), in order.
pub fn expected_tensors(config: &ModelConfig) -> Result<Vec<(String, Vec<usize>)>> {
    Ok(build_from(config, Source::Declare)?.1.declared)
}

fn build_from(config: &ModelConfig, source: Source) -> Result<(Box<dyn LightField>, WeightSet)> {
    nn::build(source, |vars: &Vars| {
        Ok(match &config.family {
            Family::Srt(c) => Box::new(srt::Srt::new(vars, c)?) as Box<dyn LightField>,
            Family::Osrt(c) => Box::new(osrt::Osrt::new(vars, c)?),
            Family::Define(c) => Box::new(define::Define::new(vars, c)?),
        })
    })
}

/// Query rows `start..start + rays.rows()` of the rays of some views, `per_view` rays a view: the rays, and
/// the camera positions `[views, 3]` they are cast from (row r's is camera_pos[(start + r) / per_view]).
/// What a decoder turns into queries, whole or one chunk at a time ([`slice`](Self::slice)).
#[derive(Clone, Copy, Debug)]
pub struct QueryRows {
    pub camera_pos: Tensor,
    pub per_view: usize,
    pub start: usize,
    pub rays: Tensor,
}

impl QueryRows {
    /// The `rows` rows from `start` of these.
    pub fn slice(&self, start: usize, rows: usize) -> QueryRows {
        QueryRows { start: self.start + start, rays: self.rays.slice(start, rows), ..*self }
    }

    pub fn rows(&self) -> usize {
        self.rays.rows()
    }
}

/// The queries of a render of `views` target views on `grid` and their grid: one query per pixel (k = 1), or
/// per k×k patch, the patch rays made from full-resolution rays by the Ray-Patch decoder's resize unless the
/// grid holds patch rays already. A pinhole camera's full-resolution rays are made on the GPU from the host's
/// terms, of the kind the camera's terms carry (the host's rays for it: its own kind, which need not be the
/// family's).
pub fn target_queries(
    g: &mut Graph,
    ray_patch: Option<&RayPatchDecoder>,
    k: usize,
    views: usize,
    grid: TargetGrid,
) -> (QueryRows, ImageSize) {
    let patches = ImageSize { n: views, h: grid.height / k, w: grid.width / k };
    let full = ImageSize { n: views, h: grid.height, w: grid.width };
    let camera_pos = g.input("target_camera_pos", views, 3, HostInput::TargetCameraPos, None);
    let rays = match grid.rays {
        RaySource::Patches => g.input("target_rays", patches.pixels(), 3, HostInput::TargetRays, Some(patches)),
        RaySource::Pixels => g.input("target_rays", full.pixels(), 3, HostInput::TargetRays, Some(full)),
        RaySource::Pinhole => {
            let terms = views * (full.h + full.w);
            let terms = g.input("target_pinholes", terms, TERM_FLOATS, HostInput::TargetPinholes, None);
            let rays = g.image("target_rays", full, 3);
            let args = PinholeRaysArgs { terms: terms.view, views, height: full.h, width: full.w, out: rays.view };
            pinhole_rays(&mut g.b, "target_rays", args);
            rays
        }
    };
    let rays = match ray_patch {
        Some(rp) if grid.rays != RaySource::Patches => rp.patch_rays(g, rays, patches),
        _ => rays,
    };
    (QueryRows { camera_pos, per_view: patches.h * patches.w, start: 0, rays }, patches)
}

/// The outputs of a final image of `channels` channels: rgb, and log-depth and depth from a fourth channel.
pub fn image_output_set(channels: usize) -> Outputs {
    match channels {
        4 => Outputs::of(&[Output::Rgb, Output::LogDepth, Output::Depth]),
        _ => Outputs::of(&[Output::Rgb]),
    }
}

/// Whether `outputs` needs the decoder's image (rgb, log-depth or depth).
pub fn wants_image(outputs: Outputs) -> bool {
    [Output::Rgb, Output::LogDepth, Output::Depth].into_iter().any(|o| outputs.contains(o))
}

/// The outputs of a pre-sigmoid image `[pixels, 3 or 4]`: rgb = sigmoid of its first three channels,
/// log-depth = its fourth, depth = exp(log-depth).
pub fn image_outputs(g: &mut Graph, image: Tensor, outputs: Outputs) -> Vec<(Output, Tensor)> {
    let mut out = Vec::new();
    for (output, col, channels, map, label) in [
        (Output::Rgb, 0, 3, Map::Sigmoid, "sigmoid"),
        (Output::LogDepth, 3, 1, Map::Identity, "logdepth"),
        (Output::Depth, 3, 1, Map::Exp, "depth"),
    ] {
        if outputs.contains(output) {
            let t = g.output(output.name(), image.rows(), channels);
            map_columns(&mut g.b, label, MapColumnsArgs { x: image.view, col, out: t.view, map });
            out.push((output, t));
        }
    }
    out
}

/// The image `x` resized to `to` by `resize` (a kernel of `kernels::resize`) into a new image named `path`.
pub fn resized(g: &mut Graph, path: &str, x: Tensor, to: ImageSize, resize: ResizeKernel) -> Tensor {
    let out = g.image(path, to, x.cols);
    resize_into(g, path, x, out, to, resize);
    out
}

/// Records `resize` of the image `x` into `out` (`to.pixels()` rows: an image or a plan output), labelled `path`.
pub fn resize_into(g: &mut Graph, path: &str, x: Tensor, out: Tensor, to: ImageSize, resize: ResizeKernel) {
    let from = x.size();
    let label = g.label(path);
    let args =
        ResizeArgs { x: x.view, n: from.n, from: (from.h, from.w), out: out.view, to: (to.h, to.w), accumulate: false };
    resize(&mut g.b, &label, args);
}

/// A kernel of `kernels::resize` ([`bilinear`](crate::kernels::resize::bilinear) or
/// [`nearest`](crate::kernels::resize::nearest)).
pub type ResizeKernel = fn(&mut PlanBuilder, &str, ResizeArgs);

/// Decoder queries are processed in chunks whose widest intermediate stays under this many bytes, so that
/// memory is bounded at any resolution. Chunks start at multiples of 64 rows (buffer offset alignment).
const CHUNK_BYTES: usize = 32 << 20;
const CHUNK_ALIGN: usize = 64;

/// Records `decode(g, start, rows)` for each chunk of `queries` rows whose widest intermediate has `widest`
/// columns, with the chunk's rows as the label suffix (e.g. `[0..4096]`).
pub fn in_query_chunks(g: &mut Graph, queries: usize, widest: usize, mut decode: impl FnMut(&mut Graph, usize, usize)) {
    for chunk in query_chunks(g, queries, widest) {
        g.with_suffix(format!("[{}..{}]", chunk.start, chunk.end), |g| decode(g, chunk.start, chunk.len()));
    }
}

/// The query chunks of `queries` rows whose widest intermediate has `widest` columns.
fn query_chunks(g: &Graph, queries: usize, widest: usize) -> Vec<Range<usize>> {
    let chunk_bytes = CHUNK_BYTES.min(usize::try_from(g.max_buffer_bytes).unwrap_or(usize::MAX));
    let chunk = (chunk_bytes / (4 * padded_cols(widest))) / CHUNK_ALIGN * CHUNK_ALIGN;
    let chunk = chunk.clamp(CHUNK_ALIGN, queries.div_ceil(CHUNK_ALIGN) * CHUNK_ALIGN);
    (0..queries).step_by(chunk).map(|start| start..(start + chunk).min(queries)).collect()
}
