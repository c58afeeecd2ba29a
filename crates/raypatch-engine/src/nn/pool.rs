//! `nn.MaxPool2d(kernel, stride, padding)` on NHWC images (no weights).

use crate::graph::{Graph, ImageSize, Tensor};
use crate::kernels::pool::{max_pool2d, pool_output_size, PoolArgs};
use crate::kernels::Window;

pub struct MaxPool2d {
    pub path: String,
    pub window: Window,
}

impl MaxPool2d {
    /// `nn.MaxPool2d(kernel, stride, padding)` (dilation 1, `ceil_mode=False`) at `path` (for op labels).
    pub fn new(path: &str, kernel: usize, stride: usize, padding: usize) -> MaxPool2d {
        MaxPool2d { path: path.to_string(), window: Window { kernel, stride, padding } }
    }

    /// The output size for an input of `size`: `(h + 2·padding − k) / stride + 1`. Panics when the window
    /// does not fit the (padded) input.
    pub fn output(&self, size: ImageSize) -> ImageSize {
        let Some((h, w)) = pool_output_size(size.h, size.w, self.window) else {
            panic!("{}: a {:?} does not fit a {}x{} image", self.path, self.window, size.h, size.w);
        };
        ImageSize { h, w, ..size }
    }

    /// The pooled image, a new image with `x`'s channels.
    pub fn forward(&self, g: &mut Graph, x: Tensor) -> Tensor {
        let out = g.image(&self.path, self.output(x.size()), x.cols);
        let ImageSize { n, h, w } = x.size();
        let label = g.label(&self.path);
        max_pool2d(&mut g.b, &label, PoolArgs { x: x.view, n, h, w, out: out.view, window: self.window });
        out
    }
}
