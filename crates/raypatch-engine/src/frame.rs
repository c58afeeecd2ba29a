//! What a render is asked for and what it returns: the outputs (a named set), the region, the frame of
//! rendered outputs, and the crop of the target image a render computes.

use raypatch_model::pinhole::{PinholeRays, TERM_FLOATS};
use raypatch_model::{TargetGrid, TargetRays, TargetViews};

/// An output a model can render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Output {
    /// The colour image, after the sigmoid: 3 channels.
    Rgb,
    /// The log-depth channel of models with 4 output channels, as the official model returns it.
    LogDepth,
    /// Depth = exp(log-depth): 1 channel.
    Depth,
    /// OSRT's slot-mixer weights per pixel: one channel per slot, summing to 1.
    Segmentation,
}

impl Output {
    /// Every output, in the order frames list them.
    pub const ALL: [Output; 4] = [Output::Rgb, Output::LogDepth, Output::Depth, Output::Segmentation];

    /// The output's name in the CLI, raw output files and messages.
    pub fn name(self) -> &'static str {
        match self {
            Output::Rgb => "rgb",
            Output::LogDepth => "logdepth",
            Output::Depth => "depth",
            Output::Segmentation => "segmentation",
        }
    }

    /// The output's name in sentences.
    pub fn title(self) -> &'static str {
        match self {
            Output::Rgb => "rgb",
            Output::LogDepth => "log-depth",
            Output::Depth => "depth",
            Output::Segmentation => "segmentation",
        }
    }

    /// What a model that cannot render this output lacks, for messages.
    pub fn lacked(self) -> &'static str {
        match self {
            Output::Rgb => "no rgb output",
            Output::LogDepth | Output::Depth => "no depth channel",
            Output::Segmentation => "no object slots (segmentation is an OSRT output)",
        }
    }

    /// The output named `name`, if any.
    pub fn from_name(name: &str) -> Option<Output> {
        Output::ALL.into_iter().find(|o| o.name() == name)
    }

    fn bit(self) -> u32 {
        1 << self as u32
    }
}

/// A set of outputs. A render computes only those asked for: without rgb the sigmoid is not run, without
/// log-depth the log-depth channel is not copied out; an OSRT render without rgb (or depth) stops at the
/// slot-mixer weights, and one without segmentation reads no weights back.
///
/// ```
/// use raypatch_engine::{Output, Outputs};
/// assert_eq!(Outputs::default(), Outputs::of(&[Output::Rgb]));
/// assert!(Outputs::of(&[Output::Rgb, Output::LogDepth]).contains(Output::LogDepth));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Outputs(u32);

impl Outputs {
    pub const NONE: Outputs = Outputs(0);

    pub fn of(outputs: &[Output]) -> Outputs {
        Outputs(outputs.iter().fold(0, |bits, o| bits | o.bit()))
    }
    pub fn contains(self, output: Output) -> bool {
        self.0 & output.bit() != 0
    }
    pub fn with(self, output: Output) -> Outputs {
        Outputs(self.0 | output.bit())
    }
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// The outputs of `self` that `other` lacks.
    pub fn missing_from(self, other: Outputs) -> impl Iterator<Item = Output> {
        self.iter().filter(move |o| !other.contains(*o))
    }
    pub fn iter(self) -> impl Iterator<Item = Output> {
        Output::ALL.into_iter().filter(move |o| self.contains(*o))
    }
}

impl Default for Outputs {
    fn default() -> Self {
        Outputs::of(&[Output::Rgb])
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
/// use raypatch_engine::{Output, Outputs, Region, Request};
/// let full: Request = Outputs::default().into();
/// assert_eq!(full.region, None);
/// let corner = Request { region: Some(Region { x: 0, y: 0, width: 8, height: 8 }), ..full };
/// assert!(corner.outputs.contains(Output::Rgb));
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

/// The values of one rendered output: `[views, height, width, channels]`.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputValues {
    pub output: Output,
    pub channels: usize,
    pub values: Vec<f32>,
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
    /// The requested outputs, in [`Output::ALL`] order.
    pub outputs: Vec<OutputValues>,
}

impl Frame {
    /// The values of `output`, `[views, height, width, channels]`, when it was rendered.
    pub fn get(&self, output: Output) -> Option<&[f32]> {
        self.outputs.iter().find(|r| r.output == output).map(|r| r.values.as_slice())
    }

    /// Takes the values of `output` out of the frame.
    pub fn take(&mut self, output: Output) -> Option<Vec<f32>> {
        let i = self.outputs.iter().position(|r| r.output == output)?;
        Some(self.outputs.remove(i).values)
    }
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
    /// Multiply-adds per render, counted from the recorded ops.
    pub multiply_adds: u64,
    /// Bytes the render's plans allocated (intermediates, inputs, outputs, params).
    pub peak_bytes: u64,
    /// Bytes of one run's staging (the host-visible buffers its inputs and outputs go through), kept with
    /// the plans: a render keeps one per run in flight.
    pub staging_bytes: u64,
    /// Bytes of the largest tensor a plan binds as one buffer (at most `Gpu::max_buffer_bytes`).
    pub largest_buffer_bytes: u64,
    /// Row bands the render runs in: 1 unless a buffer of the whole render would exceed the GPU's limit.
    pub bands: usize,
}

/// The part of a target image a render computes: whole patches covering the region and its halo.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Crop {
    /// The full image and how its rays are given.
    pub image: TargetGrid,
    /// The requested region, inside the image.
    pub region: Region,
    /// The computed pixels, patch-aligned: rows `y0..y0 + grid.height`, columns `x0..x0 + grid.width`.
    pub y0: usize,
    pub x0: usize,
    pub grid: TargetGrid,
}

impl Crop {
    /// Where the requested region lies in the computed pixels: its first row and column, its rows and columns
    /// (the readout's window, `kernels::readout`).
    pub fn read_window(&self) -> [u32; 4] {
        let r = &self.region;
        [r.y - self.y0, r.x - self.x0, r.height, r.width].map(|v| v as u32)
    }

    /// The rays of the computed pixels out of all views' ray values (`[views, height, width, 3]`), view by view
    /// and row by row; `per_ray` is the number of pixels along each axis one ray covers (1 for full-resolution
    /// rays, k for patch rays). Read in place: nothing is copied.
    pub fn rays<'t>(&self, values: &'t [f32], per_ray: usize) -> impl Iterator<Item = [f32; 3]> + 't {
        let (rh, rw) = (self.image.height / per_ray, self.image.width / per_ray);
        let (y0, x0) = (self.y0 / per_ray, self.x0 / per_ray);
        let (h, w) = (self.grid.height / per_ray, self.grid.width / per_ray);
        let views = values.len() / (rh * rw * 3);
        (0..views)
            .flat_map(move |v| (y0..y0 + h).map(move |row| ((v * rh + row) * rw + x0) * 3))
            .flat_map(move |start| values[start..start + w * 3].chunks_exact(3))
            .map(|ray| [ray[0], ray[1], ray[2]])
    }

    /// The pinhole cameras' terms of the computed pixels as the GPU reads them (`kernels::rays`): view by view,
    /// the columns' terms, then the rows'. Empty for given rays.
    pub fn pinhole_terms<'t>(&self, targets: &'t TargetViews) -> impl Iterator<Item = [f32; TERM_FLOATS]> + 't {
        let (x0, y0, w, h) = (self.x0, self.y0, self.grid.width, self.grid.height);
        let cameras: &[PinholeRays] = match &targets.rays {
            TargetRays::Pinhole(cameras) => cameras,
            TargetRays::Given(_) => &[],
        };
        cameras.iter().flat_map(move |c| c.gpu_terms(x0..x0 + w, y0..y0 + h))
    }
}
