//! Matrices packed into rgba32float textures (`shaders/pack.wgsl`, layout in `shaders/texels.wgsl`): what
//! the CPU-adapter matmul (`matmul_lanes`) reads, since llvmpipe loads a texel for 8 lanes in one call where
//! a storage-buffer load costs a bounds-checked scalar load per lane and component.

use std::hash::{Hash, Hasher};
use std::sync::Arc;

use crate::error::Result;
use crate::gpu::Gpu;
use crate::kernels::PACK;
use crate::plan::{grid, Access, KeptTexture, Op, PlanBuilder, TextureRef, View};
use crate::tensor::{padded_cols, GpuTensor};

/// How a packed matrix orders its rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
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

    /// A matrix in the row layout, nothing after it.
    pub const ROWS: Packing = Packing { layout: Layout::Rows, segments: 1, zero_rows: 0 };

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

params! {
    /// The uniform of `shaders/pack.wgsl`.
    PackParams {
        /// Rows of the packed matrix.
        rows: u32,
        /// vec4s per row of the source buffer.
        ld4: u32,
        /// Texels per packed row.
        k4p: u32,
        /// 1 (row layout) or 8 (8-lane layout).
        lanes: u32,
        /// Texels written.
        texels: u32,
        /// vec4s of the matrix per segment, and packed texels per segment.
        seg4: u32,
        seg4p: u32,
        /// The matrix's first column in the source, whether it is the transpose, and its columns.
        col: u32,
        transposed: u32,
        cols: u32,
        /// `pack_softmax_rows`' logit scale.
        scale: f32,
    }
}

/// What to pack: columns `col .. col + cols` of a view's rows, or their transpose (row `r` of the packed
/// matrix is column `col + r` of the view).
#[derive(Clone, Copy, Debug)]
pub struct Source {
    pub view: View,
    pub col: usize,
    pub cols: usize,
    pub transposed: bool,
}

impl Source {
    /// The whole view.
    pub fn all(plan: &PlanBuilder, view: View) -> Source {
        Source { view, col: 0, cols: plan.cols(view.id), transposed: false }
    }

    /// Rows and columns of the matrix packed.
    pub fn shape(&self) -> (usize, usize) {
        if self.transposed {
            (self.cols, self.view.rows)
        } else {
            (self.view.rows, self.cols)
        }
    }
}

/// A packing of a constant tensor's rows ([`PlanBuilder::constant`]) that the [`crate::Gpu`] keeps with the
/// tensor: columns `col .. col + cols`, or their transpose, packed as `packing` says.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct KeptPacking {
    pub col: usize,
    pub cols: usize,
    pub transposed: bool,
    pub packing: Packing,
}

impl KeptPacking {
    /// What it packs of `view` (the whole tensor).
    pub fn source(self, view: View) -> Source {
        Source { view, col: self.col, cols: self.cols, transposed: self.transposed }
    }
}

impl KeptTexture for KeptPacking {
    fn key(&self) -> u64 {
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        self.hash(&mut hasher);
        hasher.finish()
    }

    fn make(&self, gpu: &Gpu, name: &str, tensor: &GpuTensor) -> Result<Arc<wgpu::Texture>> {
        let mut plan = PlanBuilder::new();
        let src = plan.external(name, tensor);
        let src = self.source(plan.all(src));
        let (rows, cols) = src.shape();
        let texture = Arc::new(gpu.create_texture(&format!("{name} (packed)"), self.packing.texels(rows, cols))?);
        pack_source(&mut plan, &format!("pack {name}"), src, TextureRef::External(texture.clone()), self.packing);
        plan.build(gpu)?.execute(gpu);
        Ok(texture)
    }
}

/// `src` packed as `packing` says for the ops after this one: where it is a whole constant tensor (a model
/// weight, a scene's keys and values), the packing kept with it, made once; else packed into the plan's
/// scratch texture `slot` right here.
pub fn packed(plan: &mut PlanBuilder, label: &str, src: Source, slot: usize, packing: Packing) -> TextureRef {
    let view = src.view;
    if plan.is_constant(view.id) && view.row_start == 0 && view.rows == plan.rows(view.id) {
        let kept = KeptPacking { col: src.col, cols: src.cols, transposed: src.transposed, packing };
        return TextureRef::Kept(view.id, Arc::new(kept));
    }
    let (rows, cols) = src.shape();
    plan.scratch_texels(slot, packing.texels(rows, cols));
    pack_source(plan, label, src, TextureRef::Scratch(slot), packing);
    TextureRef::Scratch(slot)
}

/// Packs the f32 view `src` into texture `dst` as `packing` says, padding texels and zero rows zeroed.
pub fn pack(plan: &mut PlanBuilder, label: &str, src: View, dst: TextureRef, packing: Packing) {
    let src = Source::all(plan, src);
    pack_source(plan, label, src, dst, packing);
}

/// [`pack`] for part of a view, or its transpose. The columns start at a multiple of 4 unless transposed.
pub fn pack_source(plan: &mut PlanBuilder, label: &str, src: Source, dst: TextureRef, packing: Packing) {
    assert!(src.transposed || src.col.is_multiple_of(4), "{label}: packed columns start at {}", src.col);
    assert!(src.col + src.cols <= plan.cols(src.view.id), "{label}: columns past the source's");
    let params = params_for(plan, src, packing, 1.0);
    plan.push(Op {
        label: label.to_string(),
        shader: &PACK,
        entry: "pack",
        params: params.words(),
        bindings: vec![(src.view, Access::Read)],
        textures: vec![(dst, Access::Write)],
        // One workgroup per 8 packed rows (zero rows included).
        workgroups: grid((params.texels / params.k4p).div_ceil(8) as usize),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}

/// Packs softmax(scale · row) of every row of columns `col .. col + cols` of `src` into `dst` in the row
/// layout ([`Packing::ROWS`]): attention's weights from its scores, as PyTorch's `(s * scale).softmax(-1)`
/// computes them (max-subtracted). Records no multiply-adds.
pub fn pack_softmax_rows(plan: &mut PlanBuilder, label: &str, src: Source, dst: TextureRef, scale: f32) {
    assert!(!src.transposed && src.col.is_multiple_of(4), "{label}: softmax of a transposed or unaligned source");
    let params = params_for(plan, src, Packing::ROWS, scale);
    plan.push(Op {
        label: label.to_string(),
        shader: &PACK,
        entry: "pack_softmax_rows",
        params: params.words(),
        bindings: vec![(src.view, Access::Read)],
        textures: vec![(dst, Access::Write)],
        workgroups: grid(src.view.rows.div_ceil(64)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}

fn params_for(plan: &PlanBuilder, src: Source, packing: Packing, scale: f32) -> PackParams {
    let (rows, cols) = src.shape();
    let word = |v: usize| u32::try_from(v).expect("pack param exceeds u32");
    PackParams {
        rows: word(rows),
        ld4: word(plan.ld(src.view.id) / 4),
        k4p: word(packing.texels_per_row(cols)),
        lanes: word(packing.layout.lanes()),
        texels: word(packing.texels(rows, cols)),
        seg4: word(packing.segment_vec4s(cols)),
        seg4p: word(packing.texels_per_segment(cols)),
        col: word(src.col),
        transposed: u32::from(src.transposed),
        cols: word(cols),
        scale,
    }
}
