//! SRT and RP-SRT as plans of kernels, mirroring the official modules (tberriel/RayPatchQuerying):
//! `SRTEncoder` → latent tokens z; `SRTDecoder` (ray queries cross-attending to z) → per-ray features;
//! `RayPatchDecoder` (conv upsampler with RGB skips) for Ray-Patch; then the sigmoid.
//!
//! A scene is encoded once ([`Model::encode`]); the decoder's keys and values are projected from z then,
//! once per layer, and kept. Rendering ([`EncodedScene::render`]) builds a plan per (target count, computed
//! size, outputs) on first use and reuses it; it computes only the requested outputs, and for a region of
//! interest only the patches that region depends on.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use raypatch_model::{InputViews, LoadedModel, ModelConfig, Octaves, TargetGrid, TargetViews};

use crate::error::{EngineError, Result};
use crate::gpu::Gpu;
use crate::kernels::attention::{attention, AttentionArgs};
use crate::kernels::conv::{conv3x3, Conv3x3Args};
use crate::kernels::elementwise::{map_columns, Map, MapColumnsArgs};
use crate::kernels::matmul::{linear, LinearArgs};
use crate::kernels::norm::{layernorm, LayerNormArgs};
use crate::kernels::posenc::{self, FourierArgs};
use crate::kernels::resize::{self, ResizeArgs};
use crate::kernels::Activation;
use crate::plan::{Plan, PlanBuilder, TensorId, View};
use crate::tensor::{padded_cols, GpuTensor};
use crate::weights::{Conv3x3, KeptF32, LayerNorm, Linear, LoadOptions, SrtWeights};

/// LayerNorm eps of every official transformer.
const LAYER_NORM_EPS: f32 = 1e-5;
/// LeakyReLU slopes: the decoder's out_mlp (nn.LeakyReLU default) and the Ray-Patch conv decoder.
const OUT_MLP_SLOPE: f32 = 0.01;
const CONV_DECODER_SLOPE: f32 = 0.2;
/// Decoder queries are processed in chunks whose widest intermediate stays under this many bytes, so that
/// memory is bounded at any resolution. Chunks start at multiples of 64 rows (buffer offset alignment).
const CHUNK_BYTES: usize = 32 << 20;
const CHUNK_ALIGN: usize = 64;

/// Each op's label and wall time, in plan order (from the profiling entry points).
pub type OpTimes = Vec<(String, std::time::Duration)>;

/// A loaded model with its weights on the GPU.
pub struct Model {
    gpu: Arc<Gpu>,
    pub config: ModelConfig,
    pub path: String,
    pub parameter_count: usize,
    weights: SrtWeights,
}

/// Which outputs a render computes. Only these are computed: without `rgb` the sigmoid is not run, without
/// `logdepth` the log-depth channel is not copied out.
///
/// ```
/// use raypatch_engine::Outputs;
/// assert_eq!(Outputs::default(), Outputs { rgb: true, logdepth: false });
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Outputs {
    /// The colour image, after the sigmoid.
    pub rgb: bool,
    /// The log-depth channel of models with 4 output channels.
    pub logdepth: bool,
}

impl Default for Outputs {
    fn default() -> Self {
        Outputs { rgb: true, logdepth: false }
    }
}

/// A rectangle of the target image in pixels: columns `x..x + width`, rows `y..y + height` (row 0 = top).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Region {
    /// First column.
    pub x: usize,
    /// First row.
    pub y: usize,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl Region {
    /// Whether the region lies inside a `width` x `height` image (an empty region at its edge does too); no
    /// sum overflows, however large the numbers.
    pub fn lies_within(&self, width: usize, height: usize) -> bool {
        let fits = |start: usize, len: usize, size: usize| start.checked_add(len).is_some_and(|end| end <= size);
        fits(self.x, self.width, width) && fits(self.y, self.height, height)
    }
}

/// What a render computes: the outputs, and the region of the image (the whole image when `None`).
///
/// Only the patches (one query each; pixels for SRT) that the region's pixels depend on are decoded: for
/// Ray-Patch, the region plus the halo the conv decoder's receptive field needs, so the region's pixels
/// equal those of a full render. Everything else is not computed.
///
/// ```
/// use raypatch_engine::{Outputs, Region, Request};
/// let full: Request = Outputs::default().into();
/// assert_eq!(full.region, None);
/// let corner = Request { region: Some(Region { x: 0, y: 0, width: 8, height: 8 }), ..full };
/// assert!(corner.outputs.rgb);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Request {
    /// What to compute.
    pub outputs: Outputs,
    /// Where (the whole image when `None`).
    pub region: Option<Region>,
}

impl From<Outputs> for Request {
    fn from(outputs: Outputs) -> Self {
        Request { outputs, region: None }
    }
}

/// Rendered target views: the requested outputs over the requested region.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Number of target views.
    pub views: usize,
    /// Rows of the region rendered (the whole image when no region was asked for).
    pub height: usize,
    /// Columns of the region rendered.
    pub width: usize,
    /// Where the region lies in the target image.
    pub region: Region,
    /// `[views, height, width, 3]` after the sigmoid, when requested.
    pub rgb: Option<Vec<f32>>,
    /// `[views, height, width]` when requested.
    pub logdepth: Option<Vec<f32>>,
}

/// What a render plan computes, for checking what work is skipped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderStats {
    /// Decoder queries (one per patch for Ray-Patch, one per pixel for SRT), over all views and bands.
    pub queries: usize,
    /// Pixels the plans produce per view (the region plus its halo, rounded out to whole patches; bands
    /// overlap by their halos).
    pub pixels: usize,
    /// Kernel dispatches per render.
    pub dispatches: usize,
    /// Bytes the render's plans allocated (intermediates, inputs, outputs, params).
    pub peak_bytes: u64,
    /// Bytes of the largest tensor a plan binds as one buffer (at most [`Gpu::max_buffer_bytes`]).
    pub largest_buffer_bytes: u64,
    /// Row bands the render runs in: 1 unless a buffer of the whole render would exceed the GPU's limit.
    pub bands: usize,
}

/// A scene encoded by a model: the latent tokens and, per decoder layer, their keys and values.
pub struct EncodedScene<'m> {
    model: &'m Model,
    /// z: `[tokens, token_dim]`.
    pub latent: GpuTensor,
    /// Per decoder layer: `to_kv(z)` as `[tokens, 2·inner]` (keys, then values).
    pub keys_values: Vec<GpuTensor>,
    /// Bytes the encode plan allocated (its intermediates; freed after encoding).
    pub encode_peak_bytes: u64,
    render_plans: Mutex<HashMap<RenderKey, Arc<RenderGraph>>>,
}

/// A render plan is built per target count, computed image size (the whole image, or a region with its
/// halo), ray resolution and outputs; the region's position only changes which rays are uploaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct RenderKey {
    views: usize,
    grid: TargetGrid,
    outputs: Outputs,
}

struct RenderGraph {
    plan: Plan,
    ids: RenderIds,
    largest_tensor_bytes: u64,
}

/// The tensors of a render plan the host writes or reads.
struct RenderIds {
    target_pos: TensorId,
    target_rays: TensorId,
    rgb: Option<TensorId>,
    logdepth: Option<TensorId>,
    queries: usize,
}

/// The part of a target image a render computes: whole patches covering the region and its halo.
#[derive(Clone, Copy, Debug)]
struct Crop {
    /// The full image and how its rays are given.
    image: TargetGrid,
    /// The requested region, inside the image.
    region: Region,
    /// The computed pixels, patch-aligned: rows `y0..y0 + grid.height`, columns `x0..x0 + grid.width`.
    y0: usize,
    x0: usize,
    grid: TargetGrid,
}

impl Model {
    pub fn load(gpu: Arc<Gpu>, path: impl AsRef<Path>) -> Result<Model> {
        let loaded = raypatch_model::load_model(path)?;
        Model::from_loaded(gpu, &loaded)
    }

    pub fn from_loaded(gpu: Arc<Gpu>, loaded: &LoadedModel) -> Result<Model> {
        Model::from_loaded_with(gpu, loaded, &LoadOptions::default())
    }

    /// [`from_loaded`](Self::from_loaded) with options (f16 weights).
    pub fn from_loaded_with(gpu: Arc<Gpu>, loaded: &LoadedModel, options: &LoadOptions) -> Result<Model> {
        let weights = SrtWeights::upload(&gpu, loaded, options)?;
        Ok(Model {
            gpu,
            config: loaded.config.clone(),
            path: loaded.path.clone(),
            parameter_count: loaded.parameter_count(),
            weights,
        })
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Bytes of GPU memory the weights take.
    pub fn weight_bytes(&self) -> u64 {
        self.weights.bytes
    }

    /// Linear layers kept in f32 under f16 weight storage (a weight beyond f16's range).
    pub fn weights_kept_f32(&self) -> &[KeptF32] {
        &self.weights.kept_f32
    }

    /// Encodes posed input views into latent tokens and the decoder's keys and values. Waits for the GPU.
    pub fn encode(&self, inputs: &InputViews) -> Result<EncodedScene<'_>> {
        self.encode_inner(inputs, false).map(|(scene, _)| scene)
    }

    /// Like [`encode`](Self::encode), running the ops one by one and timing each (slower; for profiling).
    pub fn encode_profiled(&self, inputs: &InputViews) -> Result<(EncodedScene<'_>, OpTimes)> {
        self.encode_inner(inputs, true)
    }

    fn encode_inner(&self, inputs: &InputViews, profile: bool) -> Result<(EncodedScene<'_>, OpTimes)> {
        inputs.check_for(&self.config, "input views")?;
        let gpu = &*self.gpu;
        let cfg = &self.config;
        let e = &cfg.encoder;
        let w = &self.weights.encoder;
        let (n, height, width) = (inputs.count, inputs.height, inputs.width);
        let pixels = n * height * width;
        let mut b = PlanBuilder::new();

        // Encoder input [pixels, 3 + pos + ray encodings]: RGB written by the host, encodings by the GPU.
        let in_dim = cfg.encoder_input_dim();
        let input = b.input("encoder_input", pixels, in_dim);
        let camera_pos = b.input("input_camera_pos", n, 3);
        let rays = b.input("input_rays", pixels, 3);
        let (pos_view, input_view, rays_view) = (b.all(camera_pos), b.all(input), b.all(rays));
        let pos_mult = multipliers(&e.pos_octaves);
        let ray_mult = multipliers(&e.ray_octaves);
        let (repeat, multipliers) = (height * width, &pos_mult[..]);
        let args = FourierArgs { coords: pos_view, repeat, first_row: 0, multipliers, out: input_view, col: 3 };
        posenc::fourier_encode(&mut b, "encoder.pos_enc", args);
        let (multipliers, col) = (&ray_mult[..], 3 + 6 * pos_mult.len());
        let args = FourierArgs { coords: rays_view, repeat: 1, first_row: 0, multipliers, out: input_view, col };
        posenc::fourier_encode(&mut b, "encoder.ray_enc", args);

        // SRTConvBlocks: conv(stride 1) → BN → ReLU → conv(stride 2) → BN → ReLU, BN folded.
        let (mut x, mut h, mut wd) = (input, height, width);
        for (i, (first, second)) in w.conv_blocks.iter().enumerate() {
            let hidden = b.transient(&format!("encoder.conv_blocks.{i}.hidden"), n * h * wd, first.cout);
            conv(
                &mut b,
                &format!("encoder.conv_blocks.{i}.0"),
                x,
                n,
                h,
                wd,
                first,
                hidden,
                1,
                false,
                Activation::Relu,
                false,
            );
            let (h2, w2) = (h.div_ceil(2), wd.div_ceil(2));
            let out = b.transient(&format!("encoder.conv_blocks.{i}.out"), n * h2 * w2, second.cout);
            conv(
                &mut b,
                &format!("encoder.conv_blocks.{i}.3"),
                hidden,
                n,
                h,
                wd,
                second,
                out,
                2,
                false,
                Activation::Relu,
                false,
            );
            (x, h, wd) = (out, h2, w2);
        }
        // per_patch_linear (1×1 conv) over NHWC rows gives the tokens in the official order: row-major per
        // image, images concatenated.
        let tokens = n * h * wd;
        let latent = b.output("latent", tokens, e.token_dim);
        dense(&mut b, "encoder.per_patch_linear", x, &w.per_patch_linear, latent, Activation::None, false);

        let inner = e.heads * e.dim_head;
        for (l, layer) in w.layers.iter().enumerate() {
            let p = format!("encoder.transformer.layers.{l}");
            let normed = norm(&mut b, &format!("{p}.0.norm"), latent, &layer.attn_norm);
            let qkv = b.transient(&format!("{p}.qkv"), tokens, 3 * inner);
            dense(&mut b, &format!("{p}.0.fn.to_qkv"), normed, &layer.to_qkv, qkv, Activation::None, false);
            let heads_out = b.transient(&format!("{p}.attention"), tokens, inner);
            let (q, o) = (b.all(qkv), b.all(heads_out));
            let scale = (e.dim_head as f32).powf(-0.5);
            let (k, v, out, heads, dim_head) = (q, q, o, e.heads, e.dim_head);
            let args = AttentionArgs { q, q_col: 0, k, k_col: inner, v, v_col: 2 * inner, out, heads, dim_head, scale };
            attention(&mut b, &format!("{p}.0.fn.attend"), args);
            dense(&mut b, &format!("{p}.0.fn.to_out"), heads_out, &layer.to_out, latent, Activation::None, true);
            feed_forward(&mut b, &p, latent, &layer.ff_norm, &layer.ff_in, &layer.ff_out);
        }

        // The decoder's keys and values depend only on z: project them once per scene.
        let d = &cfg.decoder;
        let kv_inner = 2 * d.heads * d.dim_head;
        let keys_values: Vec<TensorId> = self
            .weights
            .decoder
            .layers
            .iter()
            .enumerate()
            .map(|(l, layer)| {
                let kv = b.output(&format!("decoder.layers.{l}.kv"), tokens, kv_inner);
                dense(
                    &mut b,
                    &format!("decoder_att.ray_predictor.transformer.layers.{l}.0.fn.to_kv"),
                    latent,
                    &layer.to_kv,
                    kv,
                    Activation::None,
                    false,
                );
                kv
            })
            .collect();

        let plan = b.build(gpu).map_err(|e| match e {
            EngineError::TooLarge { what, bytes, max } => EngineError::TooLarge {
                what: format!(
                    "encoding {n} input view(s) of {width}x{height} (too many input views, or too large): {what}"
                ),
                bytes,
                max,
            },
            other => other,
        })?;
        let mut host_input = vec![0.0f32; pixels * in_dim];
        for (row, rgb) in host_input.chunks_exact_mut(in_dim).zip(inputs.images.chunks_exact(3)) {
            row[..3].copy_from_slice(rgb);
        }
        gpu.write(&plan.tensor(input), &host_input);
        gpu.write(&plan.tensor(camera_pos), &inputs.camera_pos);
        gpu.write(&plan.tensor(rays), &inputs.rays);
        let times = if profile {
            plan.profile(gpu)?
        } else {
            plan.execute(gpu);
            gpu.wait()?;
            Vec::new()
        };
        plan.check_finite(gpu, "encode", &gpu.read(&plan.tensor(latent))?)?;
        let scene = EncodedScene {
            model: self,
            latent: plan.tensor(latent),
            keys_values: keys_values.iter().map(|&id| plan.tensor(id)).collect(),
            encode_peak_bytes: plan.peak_bytes(),
            render_plans: Mutex::new(HashMap::new()),
        };
        Ok((scene, times))
    }
}

impl EncodedScene<'_> {
    /// The model that encoded this scene.
    pub fn model(&self) -> &Model {
        self.model
    }

    /// Renders the target views: the requested outputs over the requested region (see [`Request`]). The plan
    /// for this (view count, computed size, outputs) is built on first use and reused afterwards: no
    /// allocation, no pipeline compilation, one submit. Waits for the GPU.
    ///
    /// When a buffer of the render would exceed the GPU's binding limit ([`Gpu::max_buffer_bytes`]: a
    /// Ray-Patch decoder keeps full-resolution features, 157 MB at 960x1280 for the official k=2), the
    /// region is rendered in row bands, each with the halo its pixels depend on, one plan and submit each,
    /// and stitched: the same pixels as one render.
    pub fn render(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Frame> {
        let request = request.into();
        let bands = self.bands(targets, &request)?;
        if let [band] = bands.as_slice() {
            return self.render_band(targets, band, request.outputs);
        }
        let frames =
            bands.iter().map(|band| self.render_band(targets, band, request.outputs)).collect::<Result<Vec<_>>>()?;
        let region = Region { height: frames.iter().map(|f| f.height).sum(), ..frames[0].region };
        let stitch = |channels: usize, output: fn(&Frame) -> &Option<Vec<f32>>| {
            output(&frames[0]).as_ref()?;
            let mut all = Vec::with_capacity(targets.count * region.height * region.width * channels);
            for v in 0..targets.count {
                for frame in &frames {
                    let per_view = frame.height * frame.width * channels;
                    all.extend_from_slice(&output(frame).as_ref()?[v * per_view..(v + 1) * per_view]);
                }
            }
            Some(all)
        };
        Ok(Frame {
            views: targets.count,
            height: region.height,
            width: region.width,
            region,
            rgb: stitch(3, |f| &f.rgb),
            logdepth: stitch(1, |f| &f.logdepth),
        })
    }

    /// Renders one crop whose plan fits the GPU.
    fn render_band(&self, targets: &TargetViews, crop: &Crop, outputs: Outputs) -> Result<Frame> {
        let graph = self.prepare(targets, crop, outputs)?;
        let gpu = self.model.gpu();
        graph.plan.execute(gpu);
        let read = |id: Option<TensorId>| id.map(|id| gpu.read(&graph.plan.tensor(id))).transpose();
        let (rgb, logdepth) = (read(graph.ids.rgb)?, read(graph.ids.logdepth)?);
        for values in [&rgb, &logdepth].into_iter().flatten() {
            graph.plan.check_finite(gpu, "render", values)?;
        }
        let region = crop.region;
        Ok(Frame {
            views: targets.count,
            height: region.height,
            width: region.width,
            region,
            rgb: rgb.map(|v| crop.cut(&v, targets.count, 3)),
            logdepth: logdepth.map(|v| crop.cut(&v, targets.count, 1)),
        })
    }

    /// Runs the render plans op by op, timing each (slower than [`render`](Self::render); for profiling).
    pub fn profile_render(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<OpTimes> {
        let request = request.into();
        let mut times = OpTimes::new();
        for band in self.bands(targets, &request)? {
            let graph = self.prepare(targets, &band, request.outputs)?;
            times.extend(graph.plan.profile(self.model.gpu())?);
        }
        Ok(times)
    }

    /// What the render plans for these targets and this request compute (building the plans if needed).
    /// Peak bytes add up the distinct plans of the bands, which stay cached together.
    pub fn render_stats(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<RenderStats> {
        let request = request.into();
        let bands = self.bands(targets, &request)?;
        let mut stats = RenderStats {
            queries: 0,
            pixels: 0,
            dispatches: 0,
            peak_bytes: 0,
            largest_buffer_bytes: 0,
            bands: bands.len(),
        };
        let mut distinct: Vec<TargetGrid> = Vec::new();
        for crop in &bands {
            let graph = self.graph(targets.count, crop, request.outputs)?;
            stats.queries += graph.ids.queries;
            stats.pixels += crop.grid.height * crop.grid.width;
            stats.dispatches += graph.plan.dispatch_count();
            stats.largest_buffer_bytes = stats.largest_buffer_bytes.max(graph.largest_tensor_bytes);
            if !distinct.contains(&crop.grid) {
                distinct.push(crop.grid);
                stats.peak_bytes += graph.plan.peak_bytes();
            }
        }
        Ok(stats)
    }

    /// Labels of the render plans' ops, in order (building the plans if needed).
    pub fn render_op_labels(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Vec<String>> {
        let request = request.into();
        let mut labels = Vec::new();
        for crop in self.bands(targets, &request)? {
            labels.extend(self.graph(targets.count, &crop, request.outputs)?.plan.op_labels().map(String::from));
        }
        Ok(labels)
    }

    /// Number of render plans built so far (one per distinct target count, computed size and outputs).
    pub fn cached_render_plans(&self) -> usize {
        self.render_plans.lock().expect("render plan cache poisoned").len()
    }

    /// Drops the cached render plans and their buffers; the next render builds its plan again.
    pub fn clear_render_plans(&self) {
        self.render_plans.lock().expect("render plan cache poisoned").clear();
    }

    /// Checks the request against the model and the targets and works out which pixels to compute.
    fn crop(&self, targets: &TargetViews, request: &Request) -> Result<Crop> {
        let cfg = &self.model.config;
        let k = cfg.patch_size();
        let image = cfg.target_grid(targets, "target views")?;
        let outputs = request.outputs;
        if !outputs.rgb && !outputs.logdepth {
            return Err(EngineError::Request("nothing to render: ask for rgb, log-depth or both".into()));
        }
        if outputs.logdepth && cfg.image_channels() != 4 {
            return Err(EngineError::Request("log-depth was requested but this model has no depth channel".into()));
        }
        let full = Region { x: 0, y: 0, width: image.width, height: image.height };
        let region = request.region.unwrap_or(full);
        if region.width == 0 || region.height == 0 || !region.lies_within(image.width, image.height) {
            return Err(EngineError::Request(format!(
                "region x={} y={} width={} height={} is empty or not inside the {}x{} (width x height) image",
                region.x, region.y, region.width, region.height, image.width, image.height
            )));
        }
        if !image.height.is_multiple_of(k) || !image.width.is_multiple_of(k) {
            // The decoder's output is resized to the image, which mixes every patch into every pixel's
            // position: compute the whole image.
            return Ok(Crop { image, region, y0: 0, x0: 0, grid: image });
        }
        let upsample = cfg.ray_patch.as_ref().map_or(0, |rp| rp.upsample);
        let (py0, py1) = patch_span(region.y, region.y + region.height - 1, upsample, image.height / k);
        let (px0, px1) = patch_span(region.x, region.x + region.width - 1, upsample, image.width / k);
        let grid = TargetGrid {
            height: (py1 + 1 - py0) * k,
            width: (px1 + 1 - px0) * k,
            rays_are_patches: image.rays_are_patches,
        };
        Ok(Crop { image, region, y0: py0 * k, x0: px0 * k, grid })
    }

    /// The crops a render runs as: the request's own when its plan fits the GPU's buffer limit, else those of
    /// its region cut into the fewest row bands (whole patches high) whose plans fit. When nothing fits, the
    /// request's own, whose plan then reports which buffer is too large.
    fn bands(&self, targets: &TargetViews, request: &Request) -> Result<Vec<Crop>> {
        let crop = self.crop(targets, request)?;
        if self.fits(targets.count, &crop, request.outputs) {
            return Ok(vec![crop]);
        }
        let k = self.model.config.patch_size();
        let region = crop.region;
        let patch_rows = region.height.div_ceil(k);
        let mut count = 2;
        while count <= patch_rows {
            let rows = patch_rows.div_ceil(count) * k;
            let crops = (region.y..region.y + region.height)
                .step_by(rows)
                .map(|y| {
                    let band = Region { y, height: rows.min(region.y + region.height - y), ..region };
                    self.crop(targets, &Request { region: Some(band), ..*request })
                })
                .collect::<Result<Vec<_>>>()?;
            if crops.iter().any(|c| c.grid.height >= crop.grid.height) {
                break; // the bands do not shrink the computed rows (an output resize needs the whole image)
            }
            if crops.iter().all(|c| self.fits(targets.count, c, request.outputs)) {
                return Ok(crops);
            }
            count *= 2;
        }
        Ok(vec![crop])
    }

    /// Whether the render plan of this crop binds no buffer larger than the GPU allows.
    fn fits(&self, views: usize, crop: &Crop, outputs: Outputs) -> bool {
        let key = RenderKey { views, grid: crop.grid, outputs };
        if self.render_plans.lock().expect("render plan cache poisoned").contains_key(&key) {
            return true;
        }
        let (builder, _) = self.describe_render(views, crop.grid, outputs);
        builder.largest_tensor_bytes() <= self.model.gpu().max_buffer_bytes
    }

    /// The cached (or new) render plan for this many views of this crop.
    fn graph(&self, views: usize, crop: &Crop, outputs: Outputs) -> Result<Arc<RenderGraph>> {
        let key = RenderKey { views, grid: crop.grid, outputs };
        let mut plans = self.render_plans.lock().expect("render plan cache poisoned");
        if let Some(g) = plans.get(&key) {
            return Ok(g.clone());
        }
        let g = Arc::new(self.build_render(views, crop.grid, outputs)?);
        plans.insert(key, g.clone());
        Ok(g)
    }

    /// The render plan for these targets, with their cameras and the crop's rays uploaded.
    fn prepare(&self, targets: &TargetViews, crop: &Crop, outputs: Outputs) -> Result<Arc<RenderGraph>> {
        let graph = self.graph(targets.count, crop, outputs)?;
        let gpu = self.model.gpu();
        gpu.write(&graph.plan.tensor(graph.ids.target_pos), &targets.camera_pos);
        let k = if crop.image.rays_are_patches { self.model.config.patch_size() } else { 1 };
        gpu.write(&graph.plan.tensor(graph.ids.target_rays), &crop.rays(targets, k));
        Ok(graph)
    }

    fn build_render(&self, views: usize, grid: TargetGrid, outputs: Outputs) -> Result<RenderGraph> {
        let (builder, ids) = self.describe_render(views, grid, outputs);
        let largest_tensor_bytes = builder.largest_tensor_bytes();
        Ok(RenderGraph { plan: builder.build(self.model.gpu())?, ids, largest_tensor_bytes })
    }

    /// The render plan's ops and tensors, before any buffer exists.
    fn describe_render(&self, views: usize, grid: TargetGrid, outputs: Outputs) -> (PlanBuilder, RenderIds) {
        let model = self.model;
        let cfg = &model.config;
        let d = &cfg.decoder;
        let k = cfg.patch_size();
        let (ph, pw) = (grid.height / k, grid.width / k);
        let queries = views * ph * pw;
        let mut b = PlanBuilder::new();

        let target_pos = b.input("target_camera_pos", views, 3);
        let (target_rays, query_rays) = if k > 1 && !grid.rays_are_patches {
            // Patch rays: the full-resolution grid bilinearly downsampled by k, not renormalised (torchvision
            // Resize as in the official data loader).
            let full = b.input("target_rays", views * grid.height * grid.width, 3);
            let patch = b.transient("patch_rays", queries, 3);
            let (src, dst) = (b.all(full), b.all(patch));
            let from = (grid.height, grid.width);
            let args = ResizeArgs { x: src, n: views, from, out: dst, to: (ph, pw), accumulate: false };
            resize::bilinear(&mut b, "patch_rays", args);
            (full, patch)
        } else {
            let rays = b.input("target_rays", queries, 3);
            (rays, rays)
        };
        let keys_values: Vec<TensorId> = self
            .keys_values
            .iter()
            .enumerate()
            .map(|(l, kv)| b.external(&format!("decoder.layers.{l}.kv"), kv))
            .collect();

        let features = b.transient("decoder_features", queries, d.out_dims);
        let pos_mult = multipliers(&d.pos_octaves);
        let ray_mult = multipliers(&d.ray_octaves);
        let widest = [d.out_mlp_hidden, d.ff_hidden, d.input_mlp_hidden, d.heads * d.dim_head, cfg.query_dim()]
            .into_iter()
            .max()
            .unwrap_or(1);
        let chunk_bytes = CHUNK_BYTES.min(usize::try_from(model.gpu().max_buffer_bytes).unwrap_or(usize::MAX));
        let chunk = (chunk_bytes / (4 * padded_cols(widest))) / CHUNK_ALIGN * CHUNK_ALIGN;
        let chunk = chunk.clamp(CHUNK_ALIGN, queries.div_ceil(CHUNK_ALIGN) * CHUNK_ALIGN);
        for start in (0..queries).step_by(chunk) {
            let rows = chunk.min(queries - start);
            let chunk_rays = b.rows_of(query_rays, start, rows);
            let chunk_out = b.rows_of(features, start, rows);
            let queries_per_view = ph * pw;
            self.decode_chunk(
                &mut b,
                target_pos,
                queries_per_view,
                start,
                chunk_rays,
                &pos_mult,
                &ray_mult,
                &keys_values,
                chunk_out,
            );
        }

        let channels = cfg.image_channels();
        let mut image = match &model.weights.ray_patch {
            None => features,
            Some(rp) => ray_patch_decoder(&mut b, rp, features, views, ph, pw, channels),
        };
        if (ph * k, pw * k) != (grid.height, grid.width) {
            // The official RayPatchDecoder's F.interpolate(output, (h_out, w_out)): nearest, to the target size.
            let resized = b.transient("decoder_rp.resize_out", views * grid.height * grid.width, channels);
            let (src, dst) = (b.all(image), b.all(resized));
            let (from, to) = ((ph * k, pw * k), (grid.height, grid.width));
            let args = ResizeArgs { x: src, n: views, from, out: dst, to, accumulate: false };
            resize::nearest(&mut b, "decoder_rp.resize_out", args);
            image = resized;
        }
        let pixels = views * grid.height * grid.width;
        let rgb = outputs.rgb.then(|| {
            let rgb = b.output("rgb", pixels, 3);
            let (src, dst) = (b.all(image), b.all(rgb));
            map_columns(&mut b, "sigmoid", MapColumnsArgs { x: src, col: 0, out: dst, map: Map::Sigmoid });
            rgb
        });
        let logdepth = outputs.logdepth.then(|| {
            let depth = b.output("logdepth", pixels, 1);
            let (src, dst) = (b.all(image), b.all(depth));
            map_columns(&mut b, "logdepth", MapColumnsArgs { x: src, col: 3, out: dst, map: Map::Identity });
            depth
        });
        (b, RenderIds { target_pos, target_rays, rgb, logdepth, queries })
    }

    /// `SRTDecoder` on one chunk of ray queries: encode, input_mlp, cross-attention layers, out_mlp.
    #[allow(clippy::too_many_arguments)]
    fn decode_chunk(
        &self,
        b: &mut PlanBuilder,
        target_pos: TensorId,
        queries_per_view: usize,
        start: usize,
        rays: View,
        pos_mult: &[f32],
        ray_mult: &[f32],
        keys_values: &[TensorId],
        out: View,
    ) {
        let cfg = &self.model.config;
        let d = &cfg.decoder;
        let w = &self.model.weights.decoder;
        let rows = rays.rows;
        let tag = |name: &str| format!("decoder_att.{name}[{start}..{}]", start + rows);

        // q = cat(posenc(camera_pos), posenc(ray)); the position is broadcast over its view's rays.
        let query = b.transient(&tag("query"), rows, cfg.query_dim());
        let (pos, q) = (b.all(target_pos), b.all(query));
        let (repeat, multipliers) = (queries_per_view, pos_mult);
        let args = FourierArgs { coords: pos, repeat, first_row: start, multipliers, out: q, col: 0 };
        posenc::fourier_encode(b, &tag("pos_enc"), args);
        let (multipliers, col) = (ray_mult, 6 * pos_mult.len());
        let args = FourierArgs { coords: rays, repeat: 1, first_row: 0, multipliers, out: q, col };
        posenc::fourier_encode(b, &tag("ray_enc"), args);

        let hidden = b.transient(&tag("input_mlp.hidden"), rows, d.input_mlp_hidden);
        dense(b, &tag("ray_predictor.input_mlp.0"), query, &w.input_mlp.0, hidden, Activation::Relu, false);
        let x = b.transient(&tag("x"), rows, cfg.query_dim());
        dense(b, &tag("ray_predictor.input_mlp.2"), hidden, &w.input_mlp.1, x, Activation::None, false);

        let inner = d.heads * d.dim_head;
        let scale = (d.dim_head as f32).powf(-0.5);
        for (l, (layer, &kv)) in w.layers.iter().zip(keys_values).enumerate() {
            let p = tag(&format!("ray_predictor.transformer.layers.{l}"));
            let normed = norm(b, &format!("{p}.0.norm"), x, &layer.attn_norm);
            let q = b.transient(&format!("{p}.q"), rows, inner);
            dense(b, &format!("{p}.0.fn.to_q"), normed, &layer.to_q, q, Activation::None, false);
            let heads_out = b.transient(&format!("{p}.attention"), rows, inner);
            let (q, k, out) = (b.all(q), b.all(kv), b.all(heads_out));
            let (v, heads, dim_head) = (k, d.heads, d.dim_head);
            let args = AttentionArgs { q, q_col: 0, k, k_col: 0, v, v_col: inner, out, heads, dim_head, scale };
            attention(b, &format!("{p}.0.fn.attend"), args);
            dense(b, &format!("{p}.0.fn.to_out"), heads_out, &layer.to_out, x, Activation::None, true);
            feed_forward(b, &p, x, &layer.ff_norm, &layer.ff_in, &layer.ff_out);
        }

        let mut h = x;
        let last = w.out_mlp.len() - 1;
        for (i, lin) in w.out_mlp.iter().enumerate() {
            let label = tag(&format!("out_mlp.{}", 2 * i));
            if i == last {
                let src = b.all(h);
                dense_view(b, &label, src, lin, out, Activation::None, false);
            } else {
                let next = b.transient(&label, rows, d.out_mlp_hidden);
                dense(b, &label, h, lin, next, Activation::LeakyRelu(OUT_MLP_SLOPE), false);
                h = next;
            }
        }
    }
}

/// `RayPatchDecoder`: the patch features `[views·ph·pw, C]` (NHWC) upsampled 2^upsample times with summed
/// RGB skips. Returns the `[views·H·W, channels]` image before the sigmoid.
#[allow(clippy::too_many_arguments)]
fn ray_patch_decoder(
    b: &mut PlanBuilder,
    rp: &crate::weights::RayPatchWeights,
    features: TensorId,
    views: usize,
    ph: usize,
    pw: usize,
    channels: usize,
) -> TensorId {
    let p = "decoder_rp.conv_decoder";
    let (mut h, mut w) = (ph, pw);
    let first_skip = b.transient(&format!("{p}.conv_0"), views * h * w, channels);
    conv(b, &format!("{p}.conv_0"), features, views, h, w, &rp.conv_0, first_skip, 1, false, Activation::None, false);
    let mut skip = b.transient(&format!("{p}.skip.0"), views * 4 * h * w, channels);
    let (src, dst) = (b.all(first_skip), b.all(skip));
    let args = ResizeArgs { x: src, n: views, from: (h, w), out: dst, to: (2 * h, 2 * w), accumulate: false };
    resize::bilinear(b, &format!("{p}.skip.0"), args);
    let mut x = features;
    for (i, (feature_conv, to_rgb)) in rp.blocks.iter().enumerate() {
        let (h2, w2) = (2 * h, 2 * w);
        let up = b.transient(&format!("{p}.conv_blocks.{i}"), views * h2 * w2, feature_conv.cout);
        let label = format!("{p}.conv_blocks.{i}.0");
        conv(b, &label, x, views, h, w, feature_conv, up, 1, true, Activation::LeakyRelu(CONV_DECODER_SLOPE), false);
        // x_out = conv_out(x) + skip, accumulated into the upsampled skip.
        conv(b, &format!("{p}.conv_blocks.{i}.1"), up, views, h2, w2, to_rgb, skip, 1, false, Activation::None, true);
        if i + 1 < rp.blocks.len() {
            let next = b.transient(&format!("{p}.skip.{}", i + 1), views * 4 * h2 * w2, channels);
            let (src, dst) = (b.all(skip), b.all(next));
            let (from, to) = ((h2, w2), (2 * h2, 2 * w2));
            let args = ResizeArgs { x: src, n: views, from, out: dst, to, accumulate: false };
            resize::bilinear(b, &format!("{p}.skip.{}", i + 1), args);
            skip = next;
        }
        (x, h, w) = (up, h2, w2);
    }
    skip
}

impl Crop {
    /// The rays of the computed pixels; `per_ray` is the number of pixels along each axis one ray covers
    /// (1 for full-resolution rays, k for patch rays).
    fn rays<'t>(&self, targets: &'t TargetViews, per_ray: usize) -> std::borrow::Cow<'t, [f32]> {
        if self.grid == self.image {
            return targets.rays.as_slice().into();
        }
        let (rh, rw) = (self.image.height / per_ray, self.image.width / per_ray);
        let (y0, x0) = (self.y0 / per_ray, self.x0 / per_ray);
        let (h, w) = (self.grid.height / per_ray, self.grid.width / per_ray);
        cut_rows(&targets.rays, targets.count, rh, rw, 3, y0, x0, h, w).into()
    }

    /// The region's pixels out of a computed `[views, grid.height, grid.width, channels]` image.
    fn cut(&self, computed: &[f32], views: usize, channels: usize) -> Vec<f32> {
        let r = &self.region;
        let (y, x) = (r.y - self.y0, r.x - self.x0);
        cut_rows(computed, views, self.grid.height, self.grid.width, channels, y, x, r.height, r.width)
    }
}

/// The `h`×`w` window at row `y`, column `x` of each of `views` NHWC images of `height`×`width`×`channels`.
#[allow(clippy::too_many_arguments)]
fn cut_rows(
    data: &[f32],
    views: usize,
    height: usize,
    width: usize,
    channels: usize,
    y: usize,
    x: usize,
    h: usize,
    w: usize,
) -> Vec<f32> {
    let mut out = Vec::with_capacity(views * h * w * channels);
    for v in 0..views {
        for row in y..y + h {
            let start = ((v * height + row) * width + x) * channels;
            out.extend_from_slice(&data[start..start + w * channels]);
        }
    }
    out
}

/// The patches `first..=last` along an axis of `patches` patches whose decoder features the output pixels
/// `lo..=hi` depend on, through the `RayPatchDecoder` with `upsample` 2× blocks (k = 2^upsample): a 3×3 conv
/// reads one pixel further each side, and each 2× step (the nearest upsampling before a block's conv, the
/// bilinear rgb skip) reads source pixels `floor((lo-1)/2) ..= floor((hi+1)/2)`. Reads past the image edge
/// are padding in a full render too, so spans are clipped there. With these patches decoded, the pixels
/// equal those of a full render. For SRT (`upsample` 0) a patch is a pixel and nothing more is needed.
fn patch_span(lo: usize, hi: usize, upsample: usize, patches: usize) -> (usize, usize) {
    type Span = (isize, isize);
    let clip = |(lo, hi): Span, level: usize| (lo.max(0), hi.min(((patches << level) - 1) as isize));
    let grow = |(lo, hi): Span| (lo - 1, hi + 1);
    let half = |(lo, hi): Span| ((lo - 1).div_euclid(2), (hi + 1).div_euclid(2));
    let hull = |a: Span, b: Span| (a.0.min(b.0), a.1.max(b.1));
    if upsample == 0 {
        return (lo, hi);
    }
    // At each level: the skip (rgb) pixels needed, and the feature pixels needed (`x` of the next block's
    // conv, and the input of this level's to-rgb conv, which writes the skip).
    let mut skip: Span = (lo as isize, hi as isize);
    let mut features = clip(grow(skip), upsample);
    for level in (0..upsample).rev() {
        skip = clip(half(skip), level);
        features = clip(hull(half(features), grow(skip)), level);
    }
    (features.0 as usize, features.1 as usize)
}

/// The official multipliers of a Fourier encoding.
fn multipliers(o: &Octaves) -> Vec<f32> {
    posenc::multipliers(o.count, o.start, o.end)
}

/// A Linear layer from tensor `x` into tensor `out`.
fn dense(
    b: &mut PlanBuilder,
    label: &str,
    x: TensorId,
    lin: &Linear,
    out: TensorId,
    act: Activation,
    accumulate: bool,
) {
    let (xv, ov) = (b.all(x), b.all(out));
    dense_view(b, label, xv, lin, ov, act, accumulate);
}

fn dense_view(b: &mut PlanBuilder, label: &str, x: View, lin: &Linear, out: View, act: Activation, accumulate: bool) {
    let weight = b.external(label, &lin.weight);
    let bias = lin.bias.as_ref().map(|t| b.external(label, t));
    linear(b, label, LinearArgs { x, weight, bias, out, act, accumulate });
}

fn norm(b: &mut PlanBuilder, label: &str, x: TensorId, ln: &LayerNorm) -> TensorId {
    let out = b.transient(label, b.rows(x), b.cols(x));
    let gamma = b.external(label, &ln.gamma);
    let beta = b.external(label, &ln.beta);
    let (xv, ov) = (b.all(x), b.all(out));
    layernorm(b, label, LayerNormArgs { x: xv, gamma, beta, out: ov, eps: LAYER_NORM_EPS });
    out
}

/// x += FF(LN(x)), FF = Linear → GELU → Linear.
fn feed_forward(b: &mut PlanBuilder, prefix: &str, x: TensorId, ln: &LayerNorm, ff_in: &Linear, ff_out: &Linear) {
    let normed = norm(b, &format!("{prefix}.1.norm"), x, ln);
    let hidden = b.transient(&format!("{prefix}.ff"), b.rows(x), ff_in.weight.rows);
    dense(b, &format!("{prefix}.1.fn.net.0"), normed, ff_in, hidden, Activation::Gelu, false);
    dense(b, &format!("{prefix}.1.fn.net.3"), hidden, ff_out, x, Activation::None, true);
}

#[allow(clippy::too_many_arguments)]
fn conv(
    b: &mut PlanBuilder,
    label: &str,
    x: TensorId,
    n: usize,
    h: usize,
    w: usize,
    c: &Conv3x3,
    out: TensorId,
    stride: usize,
    upsample_input: bool,
    act: Activation,
    accumulate: bool,
) {
    let weight = b.external(label, &c.weight);
    let bias = c.bias.as_ref().map(|t| b.external(label, t));
    let (xv, ov) = (b.all(x), b.all(out));
    let (cin, cout) = (c.cin, c.cout);
    let args =
        Conv3x3Args { x: xv, n, h, w, cin, weight, bias, out: ov, cout, stride, upsample_input, act, accumulate };
    conv3x3(b, label, args);
}
