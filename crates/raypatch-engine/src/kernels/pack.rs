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
    /// Groups of 8 rows interleaved texel by texel: the weights w, read by 8 lanes at once.
    Lanes8,
}

impl Layout {
    fn lanes(self) -> usize {
        match self {
            Layout::Rows => 1,
            Layout::Lanes8 => 8,
        }
    }
}

/// Texels per packed row of a `cols`-wide matrix: ceil(cols / 4) rounded up to 8 (matmul_lanes reads 8 at
/// a time).
pub fn texels_per_row(cols: usize) -> usize {
    cols.div_ceil(4).div_ceil(8) * 8
}

/// Texels of a packed `[rows, cols]` matrix.
pub fn packed_texels(rows: usize, cols: usize, layout: Layout) -> usize {
    rows.div_ceil(layout.lanes()) * layout.lanes() * texels_per_row(cols)
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
    }
}

/// Packs the f32 view `src` into texture `dst` in `layout`, padding texels zeroed.
pub fn pack(plan: &mut PlanBuilder, label: &str, src: View, dst: TextureRef, layout: Layout) {
    let cols = plan.cols(src.id);
    let texels = packed_texels(src.rows, cols, layout);
    let params = PackParams {
        rows: src.rows as u32,
        ld4: (padded_cols(cols) / 4) as u32,
        k4p: texels_per_row(cols) as u32,
        lanes: layout.lanes() as u32,
        texels: texels as u32,
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
