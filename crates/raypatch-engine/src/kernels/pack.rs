//! Matrices packed into rgba32float textures (`shaders/pack.wgsl`, layout in `shaders/texels.wgsl`): what
//! the CPU-adapter matmul (`matmul_lanes`) reads, since llvmpipe loads a texel for 8 lanes in one call where
//! a storage-buffer load costs a bounds-checked scalar load per lane and component.

use crate::kernels::PACK;
use crate::plan::{grid, Access, Op, PlanBuilder, TextureRef, View};
use crate::tensor::padded_cols;

/// Texels per row of the texture (`TEXTURE_WIDTH` in `shaders/texels.wgsl`).
pub const TEXTURE_WIDTH: usize = 4096;

/// How a packed matrix orders its rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Row after row: the activations x of a matmul.
    Rows,
    /// Groups of 8 rows interleaved texel by texel, in tiles of 32 rows transposed (`shaders/texels.wgsl`): the
    /// weights w, read by 8 lanes at once, each lane storing 4 consecutive columns of out.
    Lanes8,
}

impl Layout {
    fn lanes(self) -> usize {
        match self {
            Layout::Rows => 1,
            Layout::Lanes8 => 8,
        }
    }

    /// Rows the packed matrix is rounded up to a multiple of.
    fn tile_rows(self) -> usize {
        match self {
            Layout::Rows => 1,
            Layout::Lanes8 => 32,
        }
    }
}

/// How a matrix lies in a texture: its row order, the runs each row is cut into, and zero rows after it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packing {
    pub layout: Layout,
    /// Equal runs each row is cut into, each padded to whole blocks of 8 texels (matmul_lanes reads 8 at a
    /// time): a convolution weight's k·k taps, so that the kernel steps through each tap's input channels in
    /// whole blocks. 1 for a plain matrix.
    pub segments: usize,
    /// Zero rows after the matrix's: the row a convolution's taps in the zero padding read.
    pub zero_rows: usize,
}

impl Packing {
    /// A convolution's input image (a linear layer's x: a 1 x M image): one pixel per row, then a zero pixel.
    pub const IMAGE: Packing = Packing { layout: Layout::Rows, segments: 1, zero_rows: 1 };

    /// A convolution weight with `taps` taps per row, 8 rows interleaved.
    pub const fn conv_weight(taps: usize) -> Packing {
        Packing { layout: Layout::Lanes8, segments: taps, zero_rows: 0 }
    }

    /// Source vec4s per segment of a row of a `cols`-wide matrix.
    fn segment_vec4s(self, cols: usize) -> usize {
        let vec4s = padded_cols(cols) / 4;
        assert!(
            vec4s.is_multiple_of(self.segments),
            "{cols} columns do not split into {} segments of whole vec4s",
            self.segments
        );
        vec4s / self.segments
    }

    /// Texels per packed segment: its vec4s rounded up to 8.
    pub fn texels_per_segment(self, cols: usize) -> usize {
        self.segment_vec4s(cols).div_ceil(8) * 8
    }

    /// Texels per packed row of a `cols`-wide matrix.
    pub fn texels_per_row(self, cols: usize) -> usize {
        self.segments * self.texels_per_segment(cols)
    }

    /// Texels of a packed `[rows, cols]` matrix: its rows and zero rows, rounded up to whole tiles.
    pub fn texels(self, rows: usize, cols: usize) -> usize {
        let tile = self.layout.tile_rows();
        (rows + self.zero_rows).div_ceil(tile) * tile * self.texels_per_row(cols)
    }
}

/// Width and height of a texture holding `texels` texels.
pub fn texture_size(texels: usize) -> (u32, u32) {
    (TEXTURE_WIDTH as u32, texels.div_ceil(TEXTURE_WIDTH).max(1) as u32)
}

params! {
    /// The uniform of `shaders/pack.wgsl`.
    PackParams {
        rows: u32,
        /// vec4s per row of the source buffer.
        ld4: u32,
        /// Texels per packed row.
        k4p: u32,
        /// 1 (row layout) or 8 (8-lane layout).
        lanes: u32,
        /// Texels written.
        texels: u32,
        /// Source vec4s per segment, and packed texels per segment.
        seg4: u32,
        seg4p: u32,
    }
}

/// Packs the f32 view `src` into texture `dst` as `packing` says, padding texels and zero rows zeroed.
pub fn pack(plan: &mut PlanBuilder, label: &str, src: View, dst: TextureRef, packing: Packing) {
    let cols = plan.cols(src.id);
    let texels = packing.texels(src.rows, cols);
    let params = PackParams {
        rows: src.rows as u32,
        ld4: (padded_cols(cols) / 4) as u32,
        k4p: packing.texels_per_row(cols) as u32,
        lanes: packing.layout.lanes() as u32,
        texels: texels as u32,
        seg4: packing.segment_vec4s(cols) as u32,
        seg4p: packing.texels_per_segment(cols) as u32,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &PACK,
        entry: "pack",
        params: params.words(),
        bindings: vec![(src, Access::Read)],
        textures: vec![(dst, Access::Write)],
        workgroups: grid(texels.div_ceil(64)),
        multiply_adds: 0,
    });
}
