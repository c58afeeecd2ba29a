// The uniform of the attention kernels (attention.wgsl and attention_flash.wgsl, which this prelude is
// prepended to; kernels::attention::AttentionParams): the operands' rows, columns and strides, the heads, the
// scale, and how attention_flash.wgsl splits its work (the fused kernel reads neither).

struct Params {
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
    // Keys per split (a multiple of the key tile) and the number of splits.
    split_keys: u32,
    splits: u32,
    // ceil(nq / ROWS): the fastest-varying part of the group index, so that neighbouring groups share keys.
    query_tiles: u32,
    // Floats per row of the partials: heads * (dim_head + 2).
    partial_ld: u32,
}
