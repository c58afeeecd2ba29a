//! Fused multi-head attention (self and cross) with an online softmax: one dispatch, no score matrix.

use super::ATTENTION;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

/// Query rows per workgroup (`WG * QUERIES` in `shaders/attention.wgsl`); a workgroup serves one head.
const ROWS_PER_GROUP: usize = 64 * 8;

/// Largest `dim_head`: the kernel keeps a head of each query in private arrays of `MAX_CHUNKS * 4` floats.
pub const MAX_DIM_HEAD: usize = 128;

params! {
    /// The uniform of `shaders/attention.wgsl`.
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
/// Columns need not be multiples of 4. The softmax is computed online (running max and sum per query and
/// head, max-subtracted, so logits of any magnitude are safe); memory use does not depend on `nq * nkv`.
/// Records `2·nq·nkv·dim_head·heads` multiply-adds (the scores and the weighted sum of values).
pub fn attention(plan: &mut PlanBuilder, label: &str, args: AttentionArgs) {
    let AttentionArgs { q, q_col, k, k_col, v, v_col, out, heads, dim_head, scale } = args;
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

    let word = |x: usize| u32::try_from(x).expect("attention param exceeds u32");
    let params = AttentionParams {
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
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &ATTENTION,
        entry: "attention",
        params: params.words(),
        bindings: vec![(q, Access::Read), (k, Access::Read), (v, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid(q.rows.div_ceil(ROWS_PER_GROUP) * heads),
        multiply_adds: 2 * (q.rows as u64) * (k.rows as u64) * (dim_head as u64) * (heads as u64),
    });
}
