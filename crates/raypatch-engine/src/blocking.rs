//! The native API's blocking calls: each waits on its async twin with `pollster` (on native the async code
//! blocks in `Device::poll` anyway, so nothing waits twice). A browser cannot block, so wasm builds have only
//! the async calls (`lib.rs` leaves this module out there).

use pollster::block_on;
use raypatch_model::{InputViews, TargetViews};

use crate::encoded::{EncodedScene, OpTimes, Pending};
use crate::error::{EngineError, Result};
use crate::frame::{Frame, Request};
use crate::gpu::{Gpu, GpuOptions, GpuTimes};
use crate::model::Model;
use crate::plan::{OpOutput, Plan, TensorId};
use crate::tensor::GpuTensor;

impl Gpu {
    /// [`Gpu::new_async`], waited for.
    pub fn new(options: &GpuOptions) -> Result<Gpu> {
        block_on(Gpu::new_async(options))
    }

    /// Reads a tensor back as a row-major `[rows, cols]` matrix (row padding removed). Waits for the GPU.
    pub fn read(&self, tensor: &GpuTensor) -> Result<Vec<f32>> {
        block_on(self.read_async(tensor))
    }

    /// Reads rows `[row_start, row_start + rows)` of a `cols`-wide tensor stored in `buffer`.
    pub fn read_rows(&self, buffer: &wgpu::Buffer, row_start: usize, rows: usize, cols: usize) -> Result<Vec<f32>> {
        block_on(self.read_rows_async(buffer, row_start, rows, cols))
    }

    /// Blocks until the GPU has finished all submitted work.
    pub fn wait(&self) -> Result<()> {
        block_on(self.finished())
    }

    /// [`Gpu::take_timestamps_async`], waited for.
    pub fn take_timestamps(&self) -> Result<Option<GpuTimes>> {
        block_on(self.take_timestamps_async())
    }
}

impl Plan {
    /// [`Plan::execute_and_read_async`], waited for.
    pub fn execute_and_read(
        &self,
        gpu: &Gpu,
        copies: &[(TensorId, &GpuTensor)],
        reads: &[TensorId],
    ) -> Result<Vec<Vec<f32>>> {
        block_on(self.execute_and_read_async(gpu, copies, reads))
    }

    /// [`Plan::profile_async`], waited for.
    pub fn profile(&self, gpu: &Gpu) -> Result<OpTimes> {
        block_on(self.profile_async(gpu))
    }

    /// [`Plan::execute_debug_async`], waited for.
    pub fn execute_debug(&self, gpu: &Gpu) -> Result<Vec<OpOutput>> {
        block_on(self.execute_debug_async(gpu))
    }

    /// [`Plan::first_non_finite_async`], waited for.
    pub fn first_non_finite(&self, gpu: &Gpu) -> Result<Option<OpOutput>> {
        block_on(self.first_non_finite_async(gpu))
    }

    /// [`Plan::check_finite_async`], waited for.
    pub fn check_finite(&self, gpu: &Gpu, what: &str, values: &[f32]) -> Result<()> {
        block_on(self.check_finite_async(gpu, what, values))
    }

    /// [`Plan::non_finite_async`], waited for.
    pub fn non_finite(&self, gpu: &Gpu, what: &str) -> EngineError {
        block_on(self.non_finite_async(gpu, what))
    }
}

impl Model {
    /// Encodes posed input views into the latent and what renders read. Waits for the GPU.
    pub fn encode(&self, inputs: &InputViews) -> Result<EncodedScene<'_>> {
        block_on(self.encode_async(inputs))
    }

    /// Like [`encode`](Self::encode), running the ops one by one and timing each (slower; for profiling).
    pub fn encode_profiled(&self, inputs: &InputViews) -> Result<(EncodedScene<'_>, OpTimes)> {
        block_on(self.encode_profiled_async(inputs))
    }
}

impl EncodedScene<'_> {
    /// [`EncodedScene::render_async`], waited for.
    pub fn render(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Frame> {
        block_on(self.render_async(targets, request))
    }

    /// [`render`](Self::render), each view's outputs in a frame of its own (as read back: no copy splits them).
    pub fn render_each(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<Vec<Frame>> {
        block_on(self.render_each_async(targets, request))
    }

    /// Runs the render plans op by op, timing each (slower than [`render`](Self::render); for profiling).
    pub fn profile_render(&self, targets: &TargetViews, request: impl Into<Request>) -> Result<OpTimes> {
        block_on(self.profile_render_async(targets, request))
    }

    /// Renders a sequence of target batches, each as [`render_each`](Self::render_each), keeping the GPU busy:
    /// a batch is submitted before the one before it is read back, so that the GPU renders while the host
    /// reads (and makes the next batch's rays). Batches of one size share one plan.
    pub fn render_sequence<I: Iterator<Item = TargetViews>>(&self, batches: I, request: Request) -> Renders<'_, I> {
        Renders { scene: self, request, batches, pending: None }
    }
}

/// The renders of [`EncodedScene::render_sequence`]: each batch's frames, one per view, in order.
pub struct Renders<'s, I> {
    scene: &'s EncodedScene<'s>,
    request: Request,
    batches: I,
    /// The next batch, submitted (or why it could not be).
    pending: Option<Result<(TargetViews, Pending)>>,
}

impl<I: Iterator<Item = TargetViews>> Renders<'_, I> {
    fn submit_next(&mut self) -> Option<Result<(TargetViews, Pending)>> {
        let targets = self.batches.next()?;
        Some(block_on(self.scene.submit(&targets, &self.request)).map(|pending| (targets, pending)))
    }
}

impl<I: Iterator<Item = TargetViews>> Iterator for Renders<'_, I> {
    type Item = Result<Vec<Frame>>;

    fn next(&mut self) -> Option<Result<Vec<Frame>>> {
        let current = match self.pending.take() {
            Some(pending) => pending,
            None => self.submit_next()?,
        };
        // The next batch goes to the GPU before this one is read.
        self.pending = self.submit_next();
        Some(current.and_then(|(targets, pending)| block_on(self.scene.finish(&targets, pending, true))))
    }
}
