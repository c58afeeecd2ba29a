//! Multi-head attention (self and cross), following the adapter's matmul kernel: on GPUs (`Tiled`) flash
//! attention (`shaders/attention_flash.wgsl`: a workgroup per query tile and head, a query row per invocation or,
//! with subgroups, over four lanes; keys split across workgroups when those are too few); where linear layers run on `matmul_lanes` (CPU adapters), the scores
//! of every head as one batched GEMM on it, their softmax, and the weighted sum of values as another; else
//! (`Rows`) one fused dispatch with an online softmax and no score matrix (`shaders/attention.wgsl`).

use super::{
    ATTENTION, ATTENTION_COOP, ATTENTION_COOP_8, ATTENTION_FLASH, ATTENTION_FLASH_16, ATTENTION_FLASH_8,
    ATTENTION_FLASH_LANES, ATTENTION_FLASH_LANES_16, ATTENTION_FLASH_LANES_8,
};
use crate::device::{attention_variant, splits_to_fill, AttentionVariant, CoopShape, FLASH_LANES};
use crate::gpu::Shader;
use crate::kernels::matmul::{gemm_lanes_batched, lanes_batch_fits, LanesBatch};
use crate::kernels::pack::{pack_softmax_rows, pack_source, packed, Layout, Packing, Source};
use crate::plan::{grid, Access, Op, PlanBuilder, TextureRef, View};
use crate::tensor::padded_cols;

/// Query rows per workgroup (`WG * QUERIES` in `shaders/attention.wgsl`); a workgroup serves one head.
const ROWS_PER_GROUP: usize = 64 * 8;

/// Largest `dim_head`: flash attention keeps a head of each query in 32 vec4 registers (tools/codegen/gen_attention.py
/// reads this).
pub const MAX_DIM_HEAD: usize = 128;

params! {
    /// The uniform of `shaders/attention.wgsl` and `shaders/attention_flash.wgsl` (`attention_params.wgsl`).
    AttentionParams {
        nq: u32,
        nkv: u32,
        heads: u32,
        dim_head: u32,
        q_ld: u32,
        q_col: u32,
        k_ld: u32,
        k_col: u32,
        v_ld: u32,
        v_col: u32,
        out_ld: u32,
        scale: f32,
        /// Flash attention's work split (the fused kernel reads none of these).
        split_keys: u32,
        splits: u32,
        query_tiles: u32,
        partial_ld: u32,
    }
}

impl AttentionParams {
    /// The operands' layout; no key split.
    fn of(plan: &PlanBuilder, args: &AttentionArgs) -> AttentionParams {
        let AttentionArgs { q, q_col, k, k_col, v, v_col, out, heads, dim_head, scale } = *args;
        let word = |x: usize| u32::try_from(x).expect("attention param exceeds u32");
        AttentionParams {
            nq: word(q.rows),
            nkv: word(k.rows),
            heads: word(heads),
            dim_head: word(dim_head),
            q_ld: word(plan.ld(q.id)),
            q_col: word(q_col),
            k_ld: word(plan.ld(k.id)),
            k_col: word(k_col),
            v_ld: word(plan.ld(v.id)),
            v_col: word(v_col),
            out_ld: word(plan.ld(out.id)),
            scale,
            split_keys: word(k.rows),
            splits: 1,
            query_tiles: word(q.rows.div_ceil(FLASH_ROWS)),
            partial_ld: 0,
        }
    }
}

/// An attention op's operands: see [`attention`]. Each `*_col` is where that matrix starts within its rows.
#[derive(Clone, Copy, Debug)]
pub struct AttentionArgs {
    pub q: View,
    pub q_col: usize,
    pub k: View,
    pub k_col: usize,
    pub v: View,
    pub v_col: usize,
    pub out: View,
    pub heads: usize,
    pub dim_head: usize,
    pub scale: f32,
}

/// Multi-head attention, PyTorch's `softmax(q kᵀ · scale) v` per head with heads split as `(h d)`.
///
/// For each query row `i` and head `h` (`dh = dim_head`):
/// `out[i, h*dh .. (h+1)*dh] = Σ_j softmax_j(scale · q[i, q_col + h*dh ..] · k[j, k_col + h*dh ..]) · v[j, v_col + h*dh ..]`
///
/// - `q`: `[nq, *]` view, the heads' queries at columns `q_col .. q_col + heads*dh`;
/// - `k`, `v`: `[nkv, *]` views, the keys at `k_col ..` and the values at `v_col ..`. They may be the same
///   tensor as each other and as `q` (a fused qkv matmul output with `q_col = 0, k_col = inner,
///   v_col = 2*inner`, or a cached `[nkv, 2*inner]` kv tensor with `k_col = 0, v_col = inner`);
/// - `out`: `[nq, heads*dh]` view, written whole (zero row padding);
/// - `scale` is usually `dim_head^-0.5`.
///
/// Columns need not be multiples of 4. The fused kernel computes the softmax online (running max and sum per
/// query and head, max-subtracted, so logits of any magnitude are safe) and its memory use does not depend on
/// `nq * nkv`. On `MatmulKernel::Lanes` (`attention_on_lanes`) the scores of up to [`LANES_SCORES_BYTES`] at
/// a time are materialised and their softmax max-subtracted too. Records `2·nq·nkv·dim_head·heads`
/// multiply-adds (the scores and the weighted sum of values).
pub fn attention(plan: &mut PlanBuilder, label: &str, args: AttentionArgs) {
    let AttentionArgs { q, q_col, k, k_col, v, v_col, out, heads, dim_head, .. } = args;
    if plan.failed() {
        return; // a tensor is too large to index: the plan will not be built
    }
    let inner = heads * dim_head;
    assert!(heads >= 1, "{label}: attention needs at least one head");
    assert!((1..=MAX_DIM_HEAD).contains(&dim_head), "{label}: dim_head {dim_head} outside 1..={MAX_DIM_HEAD}");
    assert!(k.rows >= 1, "{label}: attention needs at least one key");
    assert_eq!(k.rows, v.rows, "{label}: {} keys but {} values", k.rows, v.rows);
    assert_eq!(q.rows, out.rows, "{label}: {} queries but {} output rows", q.rows, out.rows);
    for (what, view, col) in [("q", q, q_col), ("k", k, k_col), ("v", v, v_col)] {
        let cols = plan.cols(view.id);
        assert!(
            col + inner <= cols,
            "{label}: {what} columns {col}..{} past the {cols} columns of {}",
            col + inner,
            plan.name(view.id)
        );
    }
    assert_eq!(plan.cols(out.id), inner, "{label}: output must have heads*dim_head = {inner} columns");
    match attention_variant(&plan.kernels, q.rows, dim_head, || LanesLayout::of(plan, &args)) {
        AttentionVariant::Lanes(layout) => return attention_on_lanes(plan, label, args, layout),
        AttentionVariant::Flash { lanes } => return flash_attention(plan, label, args, lanes),
        AttentionVariant::Coop(shape) => return coop_attention(plan, label, args, shape),
        AttentionVariant::Fused => {}
    }

    let params = AttentionParams::of(plan, &args);
    plan.push(Op {
        label: label.to_string(),
        shader: &ATTENTION,
        entry: "attention",
        params: params.words(),
        bindings: vec![(q, Access::Read), (k, Access::Read), (v, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid(q.rows.div_ceil(ROWS_PER_GROUP) * heads),
        constants: Vec::new(),
        multiply_adds: 2 * (q.rows as u64) * (k.rows as u64) * (dim_head as u64) * (heads as u64),
    });
}

/// Query rows per workgroup of `attention_flash.wgsl` (`ROWS`).
const FLASH_ROWS: usize = 64;
/// Invocations per workgroup of `attention_flash.wgsl`'s `combine` (`COMBINE_WG`).
const COMBINE_WG: usize = 64;
/// vec4s of keys (and of values) per tile in `attention_flash.wgsl`'s workgroup memory.
const FLASH_TILE_VEC4S: usize = 512;
/// Workgroups that keep a large GPU busy (an H100 has 132 multiprocessors, each running several 64-invocation
/// workgroups at once): when query tiles x heads are fewer, the keys are split across workgroups, down to one
/// key tile per split.
const FLASH_TARGET_GROUPS: usize = 1024;

/// How `attention_flash.wgsl` splits the keys of `nkv` among workgroups of a head's `query_tiles` tiles:
/// `(keys per split, splits)`, the keys per split a whole number of tiles of `tile_keys`.
pub fn flash_splits(query_tiles: usize, heads: usize, nkv: usize, tile_keys: usize) -> (usize, usize) {
    let wanted = splits_to_fill(query_tiles * heads, FLASH_TARGET_GROUPS, nkv.div_ceil(tile_keys));
    let split_keys = nkv.div_ceil(wanted).div_ceil(tile_keys) * tile_keys;
    (split_keys, nkv.div_ceil(split_keys))
}

/// Flash attention on the tensor kernels (`shaders/attention_coop.wgsl`): a workgroup per (query tile of `tile`
/// rows, head, key split), the head padded to whole output blocks of its four subgroups; with the keys split, the
/// splits' partials merged by `attention_flash.wgsl`'s `combine`.
fn coop_attention(plan: &mut PlanBuilder, label: &str, args: AttentionArgs, shape: CoopShape) {
    let tile = shape.tile as usize;
    let shader = if shape.tile == 8 { &ATTENTION_COOP_8 } else { &ATTENTION_COOP };
    let constants = vec![("COOP_LANES", f64::from(shape.lanes)), ("COOP_DH", shape.padded_head(args.dim_head) as f64)];
    let kernel = FlashKernel { shader, entry: "attention_coop", constants, combine: &ATTENTION_FLASH };
    push_flash(plan, label, args, kernel, tile, COOP_SUBGROUPS * tile);
}

/// Subgroups of an `attention_coop` workgroup (`COOP_SUBGROUPS` in the shader).
const COOP_SUBGROUPS: usize = 4;

/// Flash attention on GPUs (`shaders/attention_flash.wgsl`), each query row on `lanes` invocations (1, or
/// [`FLASH_LANES`] lanes of a subgroup): one dispatch, or with the keys split, one
/// dispatch writing each split's partial output and one merging them.
fn flash_attention(plan: &mut PlanBuilder, label: &str, args: AttentionArgs, lanes: usize) {
    // The variant whose registers hold a head (vec4s per head: 8, 16 or 32).
    let variants = match lanes {
        1 => [(8, &ATTENTION_FLASH_8), (16, &ATTENTION_FLASH_16), (32, &ATTENTION_FLASH)],
        FLASH_LANES => [(8, &ATTENTION_FLASH_LANES_8), (16, &ATTENTION_FLASH_LANES_16), (32, &ATTENTION_FLASH_LANES)],
        _ => unreachable!("flash attention runs a query row on 1 or {FLASH_LANES} lanes, not {lanes}"),
    };
    let (chunks, shader) = variants
        .into_iter()
        .find(|(chunks, _)| 4 * chunks >= args.dim_head)
        .expect("dim_head is at most MAX_DIM_HEAD = 128");
    let kernel = FlashKernel { shader, entry: "flash", constants: Vec::new(), combine: shader };
    push_flash(plan, label, args, kernel, FLASH_ROWS, FLASH_TILE_VEC4S / chunks);
}

/// A flash-attention kernel: its shader and entry point (bindings q, k, v, then the output or the partials), its
/// override constants, and the shader whose `combine` merges its key splits.
struct FlashKernel {
    shader: &'static Shader,
    entry: &'static str,
    constants: Vec<(&'static str, f64)>,
    combine: &'static Shader,
}

/// Records `kernel` over (query tile of `tile_rows` rows, head, key split), the keys split in whole tiles of
/// `tile_keys` where query tiles x heads are too few to fill a GPU ([`flash_splits`]): one dispatch writing `out`,
/// or one writing each split's partial output (each head's unnormalised output, then its m and l) and `combine`
/// merging them.
fn push_flash(
    plan: &mut PlanBuilder,
    label: &str,
    args: AttentionArgs,
    kernel: FlashKernel,
    tile_rows: usize,
    tile_keys: usize,
) {
    let AttentionArgs { q, k, v, out, heads, dim_head, .. } = args;
    let query_tiles = q.rows.div_ceil(tile_rows);
    let (split_keys, splits) = flash_splits(query_tiles, heads, k.rows, tile_keys);
    let partial_cols = heads * (dim_head + 2);
    let params = AttentionParams {
        split_keys: split_keys as u32,
        splits: splits as u32,
        query_tiles: query_tiles as u32,
        partial_ld: padded_cols(partial_cols) as u32,
        ..AttentionParams::of(plan, &args)
    };
    let written = if splits == 1 {
        out
    } else {
        let partials = plan.transient(&format!("{label}.partials"), splits * q.rows, partial_cols);
        plan.all(partials)
    };
    plan.push(Op {
        label: if splits == 1 { label.to_string() } else { format!("{label}.split") },
        shader: kernel.shader,
        entry: kernel.entry,
        params: params.words(),
        bindings: vec![(q, Access::Read), (k, Access::Read), (v, Access::Read), (written, Access::Write)],
        textures: Vec::new(),
        workgroups: grid(query_tiles * heads * splits),
        constants: kernel.constants,
        multiply_adds: 2 * (q.rows as u64) * (k.rows as u64) * (dim_head as u64) * (heads as u64),
    });
    if splits > 1 {
        plan.push(Op {
            label: format!("{label}.combine"),
            shader: kernel.combine,
            entry: "combine",
            params: params.words(),
            bindings: vec![(written, Access::Read), (out, Access::Write)],
            textures: Vec::new(),
            workgroups: grid((q.rows * params.out_ld as usize).div_ceil(COMBINE_WG)),
            constants: Vec::new(),
            multiply_adds: 0,
        });
    }
}

/// Bytes of scores `attention_on_lanes` materialises at a time: queries go in passes of whole 64-row blocks
/// (at least one) whose `heads · rows · nkv` scores fit. Their softmax, packed, takes as much again.
pub const LANES_SCORES_BYTES: usize = 16 << 20;

/// How attention is laid out on `matmul_lanes`: the packings of the queries (one run per head), the keys and
/// the transposed values, and the query rows per pass.
struct LanesLayout {
    nq: usize,
    nkv: usize,
    heads: usize,
    dim_head: usize,
    by_head: Packing,
    key_packing: Packing,
    value_packing: Packing,
    scores_ld: usize,
    /// Query rows per pass: whole 64-row blocks whose scores fit [`LANES_SCORES_BYTES`].
    rows: usize,
}

impl LanesLayout {
    /// The layout, or None where `matmul_lanes` cannot run this attention: no queries, heads not a multiple
    /// of 32 wide (a head's values must start a 32-column tile of `matmul_lanes`), columns not starting at
    /// multiples of 4, or operands too large for its textures or grid.
    fn of(plan: &PlanBuilder, args: &AttentionArgs) -> Option<LanesLayout> {
        let AttentionArgs { q, q_col, k, k_col, v_col, heads, dim_head, .. } = *args;
        let (nq, nkv, inner) = (q.rows, k.rows, heads * dim_head);
        if nq == 0 || !dim_head.is_multiple_of(32) || ![q_col, k_col, v_col].iter().all(|c| c.is_multiple_of(4)) {
            return None;
        }
        let scores_ld = padded_cols(nkv);
        let layout = LanesLayout {
            nq,
            nkv,
            heads,
            dim_head,
            // Queries and keys cut into one run per head; the values transposed, a head's dim_head rows of w each.
            by_head: Packing { layout: Layout::Rows, segments: heads, zero_rows: 0 },
            key_packing: Packing { layout: Layout::Lanes8, segments: heads, zero_rows: 0 },
            value_packing: Packing { layout: Layout::Lanes8, segments: 1, zero_rows: 0 },
            scores_ld,
            rows: (LANES_SCORES_BYTES / (heads * scores_ld * 4) / 64 * 64).max(64).min(nq),
        };
        let texels = [
            layout.by_head.texels(layout.rows, inner),
            layout.key_packing.texels(nkv, inner),
            Packing::ROWS.texels(heads * layout.rows, nkv),
            layout.value_packing.texels(inner, nkv),
        ];
        let fits = texels.iter().all(|&t| t <= plan.kernels.max_texels)
            && lanes_batch_fits(&layout.scores_batch(layout.rows))
            && lanes_batch_fits(&layout.values_batch(layout.rows));
        fits.then_some(layout)
    }

    /// The scores `q kᵀ` of `rows` queries, a GEMM per head.
    fn scores_batch(&self, rows: usize) -> LanesBatch {
        let inner = self.heads * self.dim_head;
        let head_texels = self.by_head.texels_per_segment(inner);
        LanesBatch {
            m: rows,
            n: self.nkv,
            k: self.dim_head,
            x_ld: self.by_head.texels_per_row(inner),
            x_batch: head_texels,
            w_ld: self.key_packing.texels_per_row(inner),
            w_batch: head_texels * 8,
            out_batch: rows * self.scores_ld,
            store_cols: self.scores_ld,
            batches: self.heads,
        }
    }

    /// The weighted values of `rows` queries, a GEMM per head writing its columns of out.
    fn values_batch(&self, rows: usize) -> LanesBatch {
        let weight_texels = Packing::ROWS.texels_per_row(self.nkv);
        LanesBatch {
            m: rows,
            n: self.dim_head,
            k: self.nkv,
            x_ld: weight_texels,
            x_batch: rows * weight_texels,
            w_ld: weight_texels,
            // Head h's values are rows h·dim_head.. of the transposed values: groups of 8 rows of w_ld texels.
            w_batch: self.dim_head * weight_texels,
            out_batch: self.dim_head,
            store_cols: self.dim_head,
            batches: self.heads,
        }
    }
}

/// Attention on `matmul_lanes` (what llvmpipe runs ~4x faster than the fused kernel's buffer loads): per pass
/// of query rows, the scores `q kᵀ` of all heads as one batched GEMM, `softmax(scale · scores)` packed as the
/// next GEMM's x, and `weights · v` as another batched GEMM writing each head's columns of `out`. The keys
/// and the transposed values are packed once for all passes, and once for all plans where they are constants
/// (a scene's, in cross-attention: [`crate::kernels::pack::packed`]).
fn attention_on_lanes(plan: &mut PlanBuilder, label: &str, args: AttentionArgs, layout: LanesLayout) {
    let AttentionArgs { q, q_col, k, k_col, v, v_col, out, heads, dim_head, scale } = args;
    let LanesLayout { nq, nkv, rows, by_head, key_packing, value_packing, .. } = layout;
    let inner = heads * dim_head;
    // Scratch texture 0: the queries, then the weights (as every matmul_lanes x). The keys and the values: a
    // scene's (cross-attention), packed once per scene and kept; others into scratch textures 1 and 2.
    plan.scratch_texels(0, by_head.texels(rows, inner).max(Packing::ROWS.texels(heads * rows, nkv)));
    let key_source = Source { view: k, col: k_col, cols: inner, transposed: false };
    let keys = packed(plan, &format!("{label}.pack_k"), key_source, 1, key_packing);
    let value_source = Source { view: v, col: v_col, cols: inner, transposed: true };
    let values = packed(plan, &format!("{label}.pack_v"), value_source, 2, value_packing);
    let scores = plan.transient(&format!("{label}.scores"), heads * rows, nkv);
    for first in (0..nq).step_by(rows) {
        let n = rows.min(nq - first);
        let q_rows = plan.rows_of(q.id, q.row_start + first, n);
        let out_rows = plan.rows_of(out.id, out.row_start + first, n);
        let scores = plan.rows_of(scores, 0, heads * n);
        let query_source = Source { view: q_rows, col: q_col, cols: inner, transposed: false };
        pack_source(plan, &format!("{label}.pack_q"), query_source, TextureRef::Scratch(0), by_head);
        let operands = [TextureRef::Scratch(0), keys.clone()];
        gemm_lanes_batched(plan, &format!("{label}.scores"), layout.scores_batch(n), operands, scores, q_rows);
        let weights = Source::all(plan, scores);
        pack_softmax_rows(plan, &format!("{label}.softmax"), weights, TextureRef::Scratch(0), scale);
        let operands = [TextureRef::Scratch(0), values.clone()];
        gemm_lanes_batched(plan, &format!("{label}.values"), layout.values_batch(n), operands, out_rows, q_rows);
    }
}
