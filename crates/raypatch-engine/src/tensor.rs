//! Tensors on the GPU. Every tensor is a row-major matrix `[rows, cols]` whose rows are padded to a
//! multiple of 4 floats (`ld`), so kernels can load `vec4`s along a row. The padding is always zero:
//! every kernel writes zeros into the padding of the rows it produces, and uploads pad with zeros.
//! Images are NHWC matrices: one row per pixel, one column per channel.

use std::sync::Arc;

/// Row stride, in floats, of a tensor with `cols` columns.
pub const fn padded_cols(cols: usize) -> usize {
    cols.div_ceil(4) * 4
}

/// A tensor that lives outside any plan: weights, a scene's latent and its decoder keys and values.
#[derive(Clone, Debug)]
pub struct GpuTensor {
    pub buffer: Arc<wgpu::Buffer>,
    pub rows: usize,
    pub cols: usize,
}

impl GpuTensor {
    pub fn ld(&self) -> usize {
        padded_cols(self.cols)
    }
    pub fn bytes(&self) -> u64 {
        (self.rows * self.ld() * 4) as u64
    }
}
