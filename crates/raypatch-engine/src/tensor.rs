//! Tensors on the GPU. Every tensor is a row-major matrix `[rows, cols]` whose rows are padded to a
//! multiple of 16 bytes (`ld` elements: 4 floats, or 8 halves), so kernels can load `vec4`s along a row.
//! The padding is always zero: every kernel writes zeros into the padding of the rows it produces, and
//! uploads pad with zeros. Images are NHWC matrices: one row per pixel, one column per channel.
//! Everything is f32 except weights that a model stores as f16 (see `weights::Precision`).

use std::sync::Arc;

/// Row stride, in floats, of an f32 tensor with `cols` columns.
pub const fn padded_cols(cols: usize) -> usize {
    cols.div_ceil(4) * 4
}

/// Element type of a tensor.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Dtype {
    #[default]
    F32,
    /// IEEE binary16, read by kernels as `vec4<f16>` and widened to f32 before any arithmetic.
    F16,
}

impl Dtype {
    pub const fn size(self) -> usize {
        match self {
            Dtype::F32 => 4,
            Dtype::F16 => 2,
        }
    }

    /// Row stride in elements for `cols` columns: a multiple of 16 bytes.
    pub const fn ld(self, cols: usize) -> usize {
        let per_16_bytes = 16 / self.size();
        cols.div_ceil(per_16_bytes) * per_16_bytes
    }

    pub const fn row_bytes(self, cols: usize) -> usize {
        self.ld(cols) * self.size()
    }
}

/// A tensor that lives outside any plan: weights, a scene's latent and its decoder keys and values.
#[derive(Clone, Debug)]
pub struct GpuTensor {
    pub buffer: Arc<wgpu::Buffer>,
    pub rows: usize,
    pub cols: usize,
    pub dtype: Dtype,
}

impl GpuTensor {
    pub fn ld(&self) -> usize {
        self.dtype.ld(self.cols)
    }
    pub fn bytes(&self) -> u64 {
        (self.rows * self.dtype.row_bytes(self.cols)) as u64
    }
}
