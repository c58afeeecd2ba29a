//! Recording a model into a plan: [`Graph`] wraps the [`PlanBuilder`] with typed tensor handles
//! ([`Tensor`]: rows, columns, and the image geometry where there is one), the model's GPU weights (a module's
//! [`Param`] becomes a bound tensor), the host inputs the plan expects, and the label suffix of the current
//! decoder chunk. `nn` modules and model families record through it; kernels see plain views.

use crate::gpu::Gpu;
use crate::plan::{PlanBuilder, TensorId, View};
use crate::tensor::GpuTensor;

/// A model weight as plans bind it: an index into the model's weights (`nn::WeightSet`, and once uploaded
/// the GPU weights), handed out by the `nn` modules that fetch them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Param(usize);

impl Param {
    pub(crate) fn new(index: usize) -> Param {
        Param(index)
    }

    pub fn index(self) -> usize {
        self.0
    }
}

/// `n` images of `h`×`w` pixels, NHWC: one row per pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ImageSize {
    pub n: usize,
    pub h: usize,
    pub w: usize,
}

impl ImageSize {
    pub fn pixels(&self) -> usize {
        self.n * self.h * self.w
    }
}

/// A tensor of a plan being recorded: rows `view` of a `[rows, cols]` matrix, an image when `image` is set.
#[derive(Clone, Copy, Debug)]
pub struct Tensor {
    pub view: View,
    pub cols: usize,
    pub image: Option<ImageSize>,
}

impl Tensor {
    pub fn rows(&self) -> usize {
        self.view.rows
    }
    pub fn id(&self) -> TensorId {
        self.view.id
    }
    /// The image geometry; panics for a tensor that is not an image (a bug in the model's graph).
    pub fn size(&self) -> ImageSize {
        self.image.unwrap_or_else(|| panic!("tensor {:?} is not an image", self.view.id))
    }
    /// Rows `start..start + rows` of this tensor (no longer an image).
    pub fn slice(&self, start: usize, rows: usize) -> Tensor {
        assert!(start + rows <= self.view.rows, "slice past the end of a tensor");
        let view = View { id: self.view.id, row_start: self.view.row_start + start, rows };
        Tensor { view, cols: self.cols, image: None }
    }
}

/// A per-channel normalisation of input RGB: `(v - mean) / std`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelNorm {
    pub mean: [f32; 3],
    pub std: [f32; 3],
}

/// What the host writes into an input tensor before a plan runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HostInput {
    /// Input images' RGB into columns `col..col + 3` of `[pixels, cols]` (zeros elsewhere; ops fill the rest),
    /// per channel `(v - mean) / std` when `normalize` is set (as torchvision's `Normalize` in float32).
    InputImages { col: usize, normalize: Option<ChannelNorm> },
    /// Input camera positions `[n, 3]`.
    InputCameraPos,
    /// Input rays `[pixels, 3]`.
    InputRays,
    /// Target camera positions `[views, 3]`.
    TargetCameraPos,
    /// Target rays of the computed crop, one per pixel or per patch as the target grid gives them.
    TargetRays,
    /// The pinhole cameras' column and row terms of the computed crop, from which `kernels::rays` makes the
    /// target rays (`[views * (width + height), TERM_FLOATS]`).
    TargetPinholes,
    /// Where the requested region lies in the computed crop, as u32 words (`kernels::readout`).
    ReadWindow,
    /// Zeros: a flag the plan's ops raise.
    Zeros,
}

/// A plan being recorded for one model.
pub struct Graph<'w> {
    pub b: PlanBuilder,
    weights: &'w [GpuTensor],
    /// The largest buffer the GPU binds: decoders size their query chunks under it.
    pub max_buffer_bytes: u64,
    /// Appended to op labels and tensor names (the decoder chunk, e.g. `[0..4096]`).
    suffix: String,
    pub host_inputs: Vec<(TensorId, HostInput)>,
}

impl<'w> Graph<'w> {
    pub fn new(gpu: &Gpu, weights: &'w [GpuTensor]) -> Self {
        let mut b = PlanBuilder::new();
        b.kernels = gpu.kernels;
        Graph { b, weights, max_buffer_bytes: gpu.max_buffer_bytes, suffix: String::new(), host_inputs: Vec::new() }
    }

    /// The label of an op or tensor of module `path` in the current chunk.
    pub fn label(&self, path: &str) -> String {
        format!("{path}{}", self.suffix)
    }

    /// Records `f` with `suffix` appended to every label (a decoder chunk).
    pub fn with_suffix<R>(&mut self, suffix: String, f: impl FnOnce(&mut Self) -> R) -> R {
        let outer = std::mem::replace(&mut self.suffix, suffix);
        let result = f(self);
        self.suffix = outer;
        result
    }

    fn tensor(id: TensorId, rows: usize, cols: usize, image: Option<ImageSize>) -> Tensor {
        Tensor { view: View { id, row_start: 0, rows }, cols, image }
    }

    /// An intermediate `[rows, cols]`, named `path` (plus the chunk suffix).
    pub fn transient(&mut self, path: &str, rows: usize, cols: usize) -> Tensor {
        let id = self.b.transient(&self.label(path), rows, cols);
        Self::tensor(id, rows, cols, None)
    }

    /// An intermediate image of `channels` channels.
    pub fn image(&mut self, path: &str, size: ImageSize, channels: usize) -> Tensor {
        let id = self.b.transient(&self.label(path), size.pixels(), channels);
        Self::tensor(id, size.pixels(), channels, Some(size))
    }

    /// A tensor the host writes before each run.
    pub fn input(&mut self, name: &str, rows: usize, cols: usize, what: HostInput, image: Option<ImageSize>) -> Tensor {
        let id = self.b.input(name, rows, cols);
        self.host_inputs.push((id, what));
        Self::tensor(id, rows, cols, image)
    }

    /// A tensor the host reads after a run (or keeps, for a scene).
    pub fn output(&mut self, name: &str, rows: usize, cols: usize) -> Tensor {
        let id = self.b.output(name, rows, cols);
        Self::tensor(id, rows, cols, None)
    }

    /// A scene's cached tensor, which renders read and never write (its packings are kept with it).
    pub fn scene_tensor(&mut self, name: &str, tensor: &GpuTensor) -> Tensor {
        let id = self.b.constant(name, tensor);
        Self::tensor(id, tensor.rows, tensor.cols, None)
    }

    /// A module's weight, bound into the plan.
    pub fn param(&mut self, path: &str, p: Param) -> TensorId {
        self.b.constant(path, &self.weights[p.index()])
    }
}
