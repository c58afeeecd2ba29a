//! The scene core, the same for every model family ([`LightField`](crate::models::LightField)): [`Model::encode_async`] (a [`Model`] is a
//! family's module tree with its weights on the GPU, `model.rs`) runs the encoder once per scene and keeps what
//! renders read;
//! [`EncodedScene::render_async`] records a render plan per (target count, computed size, outputs) on first use and
//! reuses it, computes only the requested outputs, and for a region only the patches it depends on, in row
//! bands when one plan would bind a buffer larger than the GPU allows.

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex};

use raypatch_model::{InputViews, RaySource, TargetGrid, TargetViews};

use crate::error::{EngineError, Result};
use crate::frame::{Crop, Frame, Output, Outputs, Region, RenderStats, Request};
use crate::gpu::storage_usage;
use crate::graph::{Graph, HostInput, ImageSize};
use crate::kernels::rays;
use crate::model::{EncodePlan, Model};
use crate::plan::TensorId;
use crate::render_io::{first_render, record_render, Recorded, RenderPlan, Sink, Submitted};
use crate::tensor::GpuTensor;

/// Each op's label and wall time, in plan order (from the profiling entry points).
pub type OpTimes = Vec<(String, std::time::Duration)>;

/// The planned GPU memory one render of several views may take (see [`EncodedScene::views_within`]): the
/// API's multi-view renders batch under it.
pub const BATCH_BUDGET_BYTES: u64 = 2 << 30;

/// A scene encoded by a model: the latent and the tensors its renders read (for SRT, each decoder layer's
/// keys and values).
pub struct EncodedScene<'m> {
    model: &'m Model,
    /// The latent: `[tokens, width]`.
    pub latent: GpuTensor,
    /// What every render reads, computed once (for SRT, per decoder layer `to_kv(z)`: keys, then values).
    pub cached: Vec<GpuTensor>,
    /// Bytes the encode plan allocated (its intermediates; kept by the model for the next encode of the same
    /// input size, freed by an encode of another size).
    pub encode_peak_bytes: u64,
    /// Multiply-adds of the encode, counted from its ops.
    pub encode_multiply_adds: u64,
    render_plans: Mutex<HashMap<PlanKey, Arc<RenderPlan>>>,
    /// Crops whose plan would bind a buffer larger than the GPU allows: a later render of the same size goes
    /// straight to its bands instead of recording the crop again to find that out.
    too_large: Mutex<HashSet<PlanKey>>,
    /// The planned bytes and largest buffer of a render of each key, as its recording gave them
    /// ([`views_within`](Self::views_within) asks per batch of a sequence: recorded once).
    sizes: Mutex<HashMap<PlanKey, (u64, u64)>>,
}

/// A render plan serves every render of this many views of this computed size with these outputs; the
/// region's position only changes which rays are uploaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct PlanKey {
    views: usize,
    grid: TargetGrid,
    outputs: Outputs,
}

impl Model {
    /// Encodes posed input views into the latent and what renders read, once the GPU is done.
    pub async fn encode_async(&self, inputs: &InputViews) -> Result<EncodedScene<'_>> {
        self.encode_inner(inputs, false).await.map(|(scene, _)| scene)
    }

    /// Like [`encode_async`](Self::encode_async), running the ops one by one and timing each (slower; for
    /// profiling).
    pub async fn encode_profiled_async(&self, inputs: &InputViews) -> Result<(EncodedScene<'_>, OpTimes)> {
        self.encode_inner(inputs, true).await
    }

    /// Multiply-adds of encoding `count` input views of `height`×`width`, counted from the encode plan's ops
    /// (recorded, not built: nothing is allocated).
    pub fn encode_multiply_adds(&self, count: usize, height: usize, width: usize) -> u64 {
        let mut g = self.graph();
        self.family.encode(&mut g, ImageSize { n: count, h: height, w: width });
        g.b.multiply_adds()
    }

    async fn encode_inner(&self, inputs: &InputViews, profile: bool) -> Result<(EncodedScene<'_>, OpTimes)> {
        inputs.check("input views")?;
        self.family.check_inputs(inputs.height, inputs.width).map_err(EngineError::Request)?;
        let gpu = &*self.gpu;
        let size = ImageSize { n: inputs.count, h: inputs.height, w: inputs.width };
        // Held until the scene's tensors are copied out: the plan's inputs and outputs are one scene's at a time.
        let mut last = self.encode_plan.lock().expect("encode plan poisoned");
        let plan = match last.take() {
            Some(plan) if plan.size == size => plan,
            previous => {
                drop(previous); // the previous size's intermediates, freed before this size's are allocated
                self.build_encode_plan(size)?
            }
        };
        let plan = last.insert(plan);
        for (id, input) in &plan.host_inputs {
            let tensor = plan.plan.tensor(*id);
            match input {
                HostInput::InputImages { col, normalize } => {
                    let mut rows = vec![0.0f32; tensor.rows * tensor.cols];
                    for (row, rgb) in rows.chunks_exact_mut(tensor.cols).zip(inputs.images.chunks_exact(3)) {
                        row[*col..col + 3].copy_from_slice(rgb);
                        if let Some(norm) = normalize {
                            for c in 0..3 {
                                row[col + c] = (row[col + c] - norm.mean[c]) / norm.std[c];
                            }
                        }
                    }
                    gpu.write(&tensor, &rows);
                }
                HostInput::InputCameraPos => gpu.write(&tensor, &inputs.camera_pos),
                HostInput::InputRays => gpu.write(&tensor, &inputs.rays),
                other => unreachable!("an encoder reads only input views, not {other:?}"),
            }
        }
        // The scene's own copies of what renders read: the plan's tensors serve the next encode.
        let own = |id: TensorId| {
            let t = plan.plan.tensor(id);
            GpuTensor { buffer: Arc::new(gpu.create_buffer("encoded scene", t.buffer.size(), storage_usage())), ..t }
        };
        let latent = own(plan.latent);
        let cached: Vec<GpuTensor> = plan.cached.iter().map(|&id| own(id)).collect();
        let copies: Vec<(TensorId, &GpuTensor)> =
            std::iter::once((plan.latent, &latent)).chain(plan.cached.iter().copied().zip(&cached)).collect();
        // Profiling times the ops one by one, then runs them again as one submit for the scene's values.
        let times = if profile { plan.plan.profile_async(gpu).await? } else { Vec::new() };
        let reads = [plan.latent];
        let reading = plan.plan.execute_and_read_async(gpu, &copies, &reads);
        // While the GPU encodes, the load's warm-up finishes, and the first encode of a size the warm-up did not
        // cover compiles the pipelines of a first render of the inputs' size (a render of another size runs the
        // same pipelines but where its size picks another kernel variant). A browser has no thread for it: there
        // it runs before the encode.
        let size_hw = (inputs.height, inputs.width);
        let warm = || {
            if self.claim_warm_up(size_hw) {
                if let Some(render) = first_render(self.graph(), &*self.family, &cached, size_hw) {
                    gpu.compile_pipelines(render.pipelines());
                }
            }
            self.finish_warm_up();
        };
        #[cfg(not(target_family = "wasm"))]
        let latent_values = std::thread::scope(|scope| {
            scope.spawn(warm);
            pollster::block_on(reading)
        });
        #[cfg(target_family = "wasm")]
        let latent_values = {
            warm();
            reading.await
        };
        let latent_values = latent_values?.remove(0);
        plan.plan.check_finite_async(gpu, "encode", &latent_values).await?;
        // Whether renders may make pinhole rays on the GPU (probed once per GPU, by the load's warm-up where it
        // ran): known before any render is planned.
        rays::exact_on(gpu).await;
        let scene = EncodedScene {
            model: self,
            latent,
            cached,
            encode_peak_bytes: plan.plan.peak_bytes(),
            encode_multiply_adds: plan.multiply_adds,
            render_plans: Mutex::new(HashMap::new()),
            too_large: Mutex::new(HashSet::new()),
            sizes: Mutex::new(HashMap::new()),
        };
        Ok((scene, times))
    }

    /// Records and builds the encode plan for input views of `size`.
    fn build_encode_plan(&self, size: ImageSize) -> Result<EncodePlan> {
        let mut g = self.graph();
        let encoded = self.family.encode(&mut g, size);
        let Graph { b, host_inputs, .. } = g;
        let multiply_adds = b.multiply_adds();
        let plan = b.build(&self.gpu).map_err(|e| match e {
            EngineError::TooLarge { what, bytes, max } => EngineError::TooLarge {
                what: format!(
                    "encoding {} input view(s) of {}x{} (too many input views, or too large): {what}",
                    size.n, size.w, size.h
                ),
                bytes,
                max,
            },
            other => other,
        })?;
        let (latent, cached) = (encoded.latent.id(), encoded.cached.iter().map(|t| t.id()).collect());
        Ok(EncodePlan { size, plan, host_inputs, latent, cached, multiply_adds })
    }
}

impl EncodedScene<'_> {
    /// The model that encoded this scene.
    pub fn model(&self) -> &Model {
        self.model
    }

    /// Renders the target views: the requested outputs over the requested region (see [`Request`]). The plan
    /// for this (view count, computed size, outputs) is built on first use and reused afterwards: no
    /// allocation, no pipeline compilation, one submit. Ready once the GPU is done.
    ///
    /// When a buffer of the render would exceed the GPU's binding limit ([`Gpu::max_buffer_bytes`](crate::gpu::Gpu::max_buffer_bytes): a
    /// Ray-Patch decoder keeps full-resolution features, 157 MB at 960x1280 for the official k=2), the
    /// region is rendered in row bands, each with the halo its pixels depend on, one plan and submit each,
    /// and stitched: the same pixels as one render.
    pub async fn render_async(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Frame> {
        let pending = self.submit(targets, &request.into()).await?;
        Ok(self.finish(targets, pending, false).await?.remove(0))
    }

    /// [`render_async`](Self::render_async), each view's outputs in a frame of its own (as read back: no copy
    /// splits them).
    pub async fn render_each_async(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Vec<Frame>> {
        let pending = self.submit(targets, &request.into()).await?;
        self.finish(targets, pending, true).await
    }

    /// Writes the inputs of every band of a render and submits them, without waiting for the GPU to run them.
    pub(crate) async fn submit(&self, targets: &TargetViews, request: &Request) -> Result<Pending> {
        let bands = self.plans(targets, request)?;
        let gpu = self.model.gpu();
        let per_ray = self.per_ray(&bands[0].0);
        let region = Region { height: bands.iter().map(|(crop, _)| crop.region.height).sum(), ..bands[0].0.region };
        let mut submitted = Vec::with_capacity(bands.len());
        for (crop, plan) in &bands {
            submitted.push(plan.submit(gpu, targets, crop, per_ray).await?);
        }
        Ok(Pending { submitted, region })
    }

    /// Waits for a submitted render and reads it: one frame of every view, or one per view.
    pub(crate) async fn finish(&self, targets: &TargetViews, pending: Pending, per_view: bool) -> Result<Vec<Frame>> {
        let Pending { submitted, region } = pending;
        let mut sink = Sink::new(submitted[0].plan(), targets.count, region, per_view);
        for band in submitted {
            let (plan, crop) = (band.plan().clone(), *band.crop());
            if !band.finish(self.model.gpu(), &mut sink).await? {
                return Err(self.non_finite(targets, &crop, &plan).await);
            }
        }
        Ok(sink.frames())
    }

    /// Why a render came out NaN or infinite: its inputs written again and its plan run op by op to the first
    /// op whose output is not finite.
    async fn non_finite(&self, targets: &TargetViews, crop: &Crop, plan: &RenderPlan) -> EngineError {
        let gpu = self.model.gpu();
        let _turn = plan.in_use.lock().expect("render plan poisoned");
        let replayed = match gpu.finished().await {
            Ok(()) => plan.write_inputs_directly(gpu, targets, crop, self.per_ray(crop)),
            Err(e) => Err(e),
        };
        match replayed {
            Ok(()) => plan.plan.non_finite_async(gpu, "render").await,
            Err(e) => e,
        }
    }

    /// Pixels along each axis that one given ray covers: k for patch rays, else 1.
    fn per_ray(&self, crop: &Crop) -> usize {
        if crop.image.rays == RaySource::Patches {
            self.model.family.patch_size()
        } else {
            1
        }
    }

    /// Runs the render plans op by op, timing each (slower than [`render`](Self::render); for profiling).
    pub async fn profile_render_async(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<OpTimes> {
        let mut times = OpTimes::new();
        for (crop, plan) in self.plans(targets, &request.into())? {
            let _turn = plan.in_use.lock().expect("render plan poisoned");
            plan.write_inputs_directly(self.model.gpu(), targets, &crop, self.per_ray(&crop))?;
            times.extend(plan.plan.profile_async(self.model.gpu()).await?);
        }
        Ok(times)
    }

    /// What the render plans for these targets and this request compute (building the plans if needed).
    /// Peak bytes add up the distinct plans of the bands, which stay cached together.
    pub fn render_stats(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<RenderStats> {
        let bands = self.plans(targets, &request.into())?;
        let mut stats = RenderStats {
            queries: 0,
            pixels: 0,
            dispatches: 0,
            multiply_adds: 0,
            peak_bytes: 0,
            staging_bytes: 0,
            largest_buffer_bytes: 0,
            bands: bands.len(),
        };
        let mut distinct: Vec<TargetGrid> = Vec::new();
        for (crop, plan) in &bands {
            stats.queries += plan.io.queries;
            stats.pixels += crop.grid.height * crop.grid.width;
            stats.dispatches += plan.plan.dispatch_count();
            stats.multiply_adds += plan.plan.multiply_adds();
            stats.largest_buffer_bytes = stats.largest_buffer_bytes.max(plan.largest_tensor_bytes);
            if !distinct.contains(&crop.grid) {
                distinct.push(crop.grid);
                stats.peak_bytes += plan.plan.peak_bytes();
                stats.staging_bytes += plan.staging_bytes();
            }
        }
        Ok(stats)
    }

    /// Multiply-adds of rendering these targets with this request, counted from the recorded ops of the
    /// request's crop (recorded, not built: nothing is allocated, so it serves to predict a render's cost).
    pub fn render_multiply_adds(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<u64> {
        let request = request.into();
        let crop = self.crop(targets, &request)?;
        Ok(self.record(targets.count, &crop, request.outputs).builder.multiply_adds())
    }

    /// How many views like `targets` one render may take at once within `budget` bytes of planned GPU memory
    /// (its plan and a staging) and the adapter's buffer limit, as the recording of this render predicts them
    /// (both grow with the views; recorded, not built: nothing is allocated); at least 1.
    pub fn views_within(&self, targets: &TargetViews, request: impl Into<Request>, budget: u64) -> Result<usize> {
        let request = request.into();
        let crop = self.crop(targets, &request)?;
        let key = PlanKey { views: targets.count, grid: crop.grid, outputs: request.outputs };
        let cached = self.sizes.lock().expect("render plan cache poisoned").get(&key).copied();
        let (planned, largest) = cached.unwrap_or_else(|| {
            let builder = self.record(targets.count, &crop, request.outputs).builder;
            let sizes = (builder.planned_bytes(), builder.largest_tensor_bytes());
            self.sizes.lock().expect("render plan cache poisoned").insert(key, sizes);
            sizes
        });
        let views = targets.count as u64;
        // A staging holds the inputs and the outputs once more: at most the plan's own bytes again.
        let per_view = (2 * planned).div_ceil(views).max(1);
        let largest = largest.div_ceil(views).max(1);
        let fit = (budget / per_view).min(self.model.gpu().max_buffer_bytes / largest);
        Ok(usize::try_from(fit).unwrap_or(usize::MAX).max(1))
    }

    /// Labels of the render plans' ops, in order (building the plans if needed).
    pub fn render_op_labels(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Vec<String>> {
        let bands = self.plans(targets, &request.into())?;
        Ok(bands.iter().flat_map(|(_, plan)| plan.plan.op_labels().map(String::from)).collect())
    }

    /// Number of render plans built so far (one per distinct target count, computed size and outputs).
    pub fn cached_render_plans(&self) -> usize {
        self.render_plans.lock().expect("render plan cache poisoned").len()
    }

    /// Drops the cached render plans and their buffers; the next render builds its plan again.
    pub fn clear_render_plans(&self) {
        self.render_plans.lock().expect("render plan cache poisoned").clear();
        self.too_large.lock().expect("render plan cache poisoned").clear();
    }

    /// Checks the request against the model and the targets and works out which pixels to compute.
    fn crop(&self, targets: &TargetViews, request: &Request) -> Result<Crop> {
        let family = &*self.model.family;
        let k = family.patch_size();
        let mut image = targets.grid_for(&self.model.config, "target views")?;
        // Probed when the scene was encoded (`rays::exact_on`); unknown counts as not exact.
        let exact = self.model.gpu().exact_pinhole_rays.get().copied().unwrap_or(false);
        if image.rays == RaySource::Pinhole && !exact {
            image.rays = RaySource::Pixels; // made by the host as the plan's inputs are written (render_io)
        }
        let outputs = request.outputs;
        if outputs.is_empty() {
            let names: Vec<&str> = family.outputs().iter().map(Output::name).collect();
            return Err(EngineError::Request(format!("nothing to render: ask for one of {}", names.join(", "))));
        }
        if let Some(missing) = outputs.missing_from(family.outputs()).next() {
            let lacks = missing.lacked();
            return Err(EngineError::Request(format!("{} was requested but this model has {lacks}", missing.title())));
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
        let (py0, py1) = family.patch_span(region.y, region.y + region.height - 1, image.height / k);
        let (px0, px1) = family.patch_span(region.x, region.x + region.width - 1, image.width / k);
        let grid = TargetGrid { height: (py1 + 1 - py0) * k, width: (px1 + 1 - px0) * k, rays: image.rays };
        Ok(Crop { image, region, y0: py0 * k, x0: px0 * k, grid })
    }

    /// The crops a render runs as, each with its plan: the request's own crop when its plan binds no buffer
    /// larger than the GPU allows, else its region cut into the fewest row bands (whole patches high) whose
    /// plans fit. When nothing fits, the request's own, whose build then reports which buffer is too large.
    /// Each plan is recorded once: measured, then built from the same recording, and cached.
    fn plans(&self, targets: &TargetViews, request: &Request) -> Result<Vec<(Crop, Arc<RenderPlan>)>> {
        let (views, outputs) = (targets.count, request.outputs);
        let crop = self.crop(targets, request)?;
        if let Some(plan) = self.cached(views, &crop, outputs) {
            return Ok(vec![(crop, plan)]);
        }
        if let Some(recorded) = self.record_if_fits(views, &crop, outputs) {
            return Ok(vec![(crop, self.build(views, crop.grid, outputs, recorded)?)]);
        }
        let k = self.model.family.patch_size();
        let region = crop.region;
        let patch_rows = region.height.div_ceil(k);
        let mut count = 2;
        'counts: while count <= patch_rows {
            let rows = patch_rows.div_ceil(count) * k;
            count *= 2;
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
            // One recording per distinct band size not built yet (equal bands share a plan).
            let mut fresh: Vec<(TargetGrid, Recorded)> = Vec::new();
            for c in &crops {
                if self.cached(views, c, outputs).is_some() || fresh.iter().any(|(grid, _)| *grid == c.grid) {
                    continue;
                }
                match self.record_if_fits(views, c, outputs) {
                    Some(recorded) => fresh.push((c.grid, recorded)),
                    None => continue 'counts,
                }
            }
            for (grid, recorded) in fresh {
                self.build(views, grid, outputs, recorded)?;
            }
            return Ok(crops
                .into_iter()
                .map(|c| {
                    let plan = self.cached(views, &c, outputs).expect("every band's plan was built");
                    (c, plan)
                })
                .collect());
        }
        let recorded = self.record(views, &crop, outputs);
        Ok(vec![(crop, self.build(views, crop.grid, outputs, recorded)?)])
    }

    /// Records the render of a crop when its plan binds no buffer larger than the GPU allows; remembers a
    /// crop size that does not fit, so that no later render records it again.
    fn record_if_fits(&self, views: usize, crop: &Crop, outputs: Outputs) -> Option<Recorded> {
        let key = PlanKey { views, grid: crop.grid, outputs };
        if self.too_large.lock().expect("render plan cache poisoned").contains(&key) {
            return None;
        }
        let recorded = self.record(views, crop, outputs);
        if recorded.builder.largest_tensor_bytes() <= self.model.gpu().max_buffer_bytes {
            return Some(recorded);
        }
        self.too_large.lock().expect("render plan cache poisoned").insert(key);
        None
    }

    fn cached(&self, views: usize, crop: &Crop, outputs: Outputs) -> Option<Arc<RenderPlan>> {
        let key = PlanKey { views, grid: crop.grid, outputs };
        self.render_plans.lock().expect("render plan cache poisoned").get(&key).cloned()
    }

    /// Records the render of `views` target views of a crop (no buffer exists yet).
    fn record(&self, views: usize, crop: &Crop, outputs: Outputs) -> Recorded {
        record_render(self.model.graph(), &*self.model.family, &self.cached, views, crop.grid, outputs)
    }

    /// Builds a recorded render plan (buffers, bind groups) and caches it; when a concurrent render cached
    /// the same key first, that plan is kept and shared.
    fn build(&self, views: usize, grid: TargetGrid, outputs: Outputs, recorded: Recorded) -> Result<Arc<RenderPlan>> {
        let plan = Arc::new(RenderPlan::new(recorded.builder, recorded.io, self.model.gpu())?);
        let key = PlanKey { views, grid, outputs };
        let mut plans = self.render_plans.lock().expect("render plan cache poisoned");
        Ok(plans.entry(key).or_insert(plan).clone())
    }
}

/// The bands of a render, submitted and not read yet.
pub(crate) struct Pending {
    submitted: Vec<Submitted>,
    /// The requested region (all bands together).
    region: Region,
}
