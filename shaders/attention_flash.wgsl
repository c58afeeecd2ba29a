// Multi-head attention for GPUs, flash-attention style: out[i, h*dh ..] = Σ_j softmax_j(scale · q_i,h · k_j,h) · v_j,h.
//
// Work split (FlashAttention-2, with flash-decoding's split of the keys): a workgroup serves one (query tile of
// ROWS = 64 rows, head, key split). LANES invocations own one query row (a prelude sets it: one, or four lanes
// of a subgroup, flash_one_lane.wgsl / flash_subgroup_lanes.wgsl): the row's scaled query and output accumulator
// stay in registers (CHUNKS vec4s a head, CHUNKS fixed per variant; REGS = CHUNKS / LANES of them in each lane,
// lane r holding chunks r, r + LANES, ...), with a running max m and sum l (online softmax: the nq x nkv scores
// never exist). The keys and values of the split go through workgroup memory a tile of TILE_KEYS keys at a
// time, loaded cooperatively (consecutive invocations read consecutive floats of a key row) and then read by
// every row at the same addresses (a broadcast). A row takes the tile's keys four at a time: their four scores
// (each lane's share summed by `lanes_sum`), the new max, one rescale of its accumulator, and the four weighted
// values.
//
// The query and the accumulator are named variables (`q_0`, `o_0`, ...), every use of them written out by
// tools/codegen/gen_attention.py between the BEGIN/END lines below: on NVIDIA's Vulkan driver an array indexed
// in a loop leaves registers (the GEMM lab of docs/PERFORMANCE.md), which is where the earlier version of this
// kernel, with arrays, spent its time. The uses of chunks past CHUNKS sit in `if (CHUNKS > ..)` blocks that
// compile away, so that the variants (32, 16 and 8 chunks, one or four lanes) share this source.
//
// When queries x heads give too few workgroups to fill a GPU (a Ray-Patch render has 300 queries: 5 tiles a
// head), the wrapper splits the keys: each split writes its unnormalised output with its m and l to the
// partials, and `combine` merges the splits of each (query, head) exactly as the online softmax would:
// M = max m_s, out = Σ e^(m_s - M) o_s / Σ e^(m_s - M) l_s. With one split `flash` writes the output itself.
//
// Operands are read as floats, so heads may start at any column (fused qkv tensors, odd dim_head); a head's
// floats past dim_head are zeros in the tiles and registers. Output rows are written whole: the last head's
// invocation zeroes the row padding.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> q: array<f32>;
@group(0) @binding(2) var<storage, read> k: array<f32>;
@group(0) @binding(3) var<storage, read> v: array<f32>;
// One split: the output [nq, out_ld]. Several: the partials [splits * nq, partial_ld], row s*nq + i holding
// head h's unnormalised output at h*(dim_head + 2), then its m and l.
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

// Query rows per workgroup (kernels::attention::FLASH_ROWS) and invocations per workgroup.
const ROWS: u32 = 64u;
const WG: u32 = ROWS * LANES;
// vec4s per head in registers: dim_head <= 4 * CHUNKS. 32 here; the wrapper's variants replace it by 16 and 8.
const CHUNKS: u32 = 32u;
// vec4s of the head in each lane's registers.
const REGS: u32 = CHUNKS / LANES;
// vec4s of keys (and as many of values) per tile: 2 x 8 KiB, within WebGPU's guaranteed 16 KiB.
const TILE_VEC4S: u32 = 512u;
// Keys per tile: 16, 32 or 64, a multiple of the 4 an invocation takes at a time.
const TILE_KEYS: u32 = TILE_VEC4S / CHUNKS;
// Stands for -inf: the running max before the first key and the score of a key past the split. exp(NEG_BIG - m)
// is 0 for any real m, and every group of four keys holds at least one real key.
const NEG_BIG: f32 = -3.0e38;

var<workgroup> k_tile: array<vec4<f32>, TILE_VEC4S>;
var<workgroup> v_tile: array<vec4<f32>, TILE_VEC4S>;

// The (query tile, head, key split) of a workgroup, and whether it has one (the grid may have more groups).
// Uniform across the workgroup, as the barriers need.
struct Tile {
    first_row: u32,
    h: u32,
    split: u32,
    valid: bool,
}

fn tile_of(wid: vec3<u32>, nwg: vec3<u32>) -> Tile {
    let g = wid.x + wid.y * nwg.x;
    let rest = g / p.query_tiles;
    return Tile((g % p.query_tiles) * ROWS, rest % p.heads, rest / p.heads, rest < p.heads * p.splits);
}

// Chunk c of query row i's head at `at` of q, scaled (zeros past the head or the queries).
fn query_chunk(i: u32, at: u32, c: u32) -> vec4<f32> {
    var chunk = vec4<f32>(0.0);
    for (var e = 0u; e < 4u; e++) {
        let d = 4u * c + e;
        if (i < p.nq && d < p.dim_head) {
            chunk[e] = q[at + d];
        }
    }
    return p.scale * chunk;
}

// Stages keys base .. base + n of head h into the tiles: slot s holds chunk s % CHUNKS of key s / CHUNKS (zeros
// past the head or the split).
fn stage_keys(lid: u32, h: u32, base: u32, n: u32) {
    let dh = p.dim_head;
    for (var slot = lid; slot < TILE_VEC4S; slot += WG) {
        let j = slot / CHUNKS;
        let c = slot % CHUNKS;
        var kc = vec4<f32>(0.0);
        var vc = vec4<f32>(0.0);
        if (j < n) {
            let k_at = (base + j) * p.k_ld + p.k_col + h * dh;
            let v_at = (base + j) * p.v_ld + p.v_col + h * dh;
            for (var e = 0u; e < 4u; e++) {
                let d = 4u * c + e;
                if (d < dh) {
                    kc[e] = k[k_at + d];
                    vc[e] = v[v_at + d];
                }
            }
        }
        k_tile[slot] = kc;
        v_tile[slot] = vc;
    }
}

// Stores chunk c of a head's output, `o` (scaled), at `at` of `out`: its floats before dim_head.
fn store_chunk(at: u32, c: u32, o: vec4<f32>) {
    for (var e = 0u; e < 4u; e++) {
        let d = 4u * c + e;
        if (d < p.dim_head) {
            out[at + d] = o[e];
        }
    }
}

@compute @workgroup_size(WG)
fn flash(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let tile = tile_of(wid, nwg);
    if (!tile.valid) {
        return; // the whole workgroup
    }
    let i = tile.first_row + lid / LANES;
    let lane = lid % LANES;
    let h = tile.h;
    let k0 = tile.split * p.split_keys;
    let k1 = min(p.nkv, k0 + p.split_keys);
    let q_at = i * p.q_ld + p.q_col + h * p.dim_head;
    // BEGIN registers: written by tools/codegen/gen_attention.py
    var q_0 = query_chunk(i, q_at, 0u * LANES + lane);
    var o_0 = vec4<f32>(0.0);
    var q_1 = query_chunk(i, q_at, 1u * LANES + lane);
    var o_1 = vec4<f32>(0.0);
    var q_2 = query_chunk(i, q_at, 2u * LANES + lane);
    var o_2 = vec4<f32>(0.0);
    var q_3 = query_chunk(i, q_at, 3u * LANES + lane);
    var o_3 = vec4<f32>(0.0);
    var q_4 = query_chunk(i, q_at, 4u * LANES + lane);
    var o_4 = vec4<f32>(0.0);
    var q_5 = query_chunk(i, q_at, 5u * LANES + lane);
    var o_5 = vec4<f32>(0.0);
    var q_6 = query_chunk(i, q_at, 6u * LANES + lane);
    var o_6 = vec4<f32>(0.0);
    var q_7 = query_chunk(i, q_at, 7u * LANES + lane);
    var o_7 = vec4<f32>(0.0);
    var q_8 = query_chunk(i, q_at, 8u * LANES + lane);
    var o_8 = vec4<f32>(0.0);
    var q_9 = query_chunk(i, q_at, 9u * LANES + lane);
    var o_9 = vec4<f32>(0.0);
    var q_10 = query_chunk(i, q_at, 10u * LANES + lane);
    var o_10 = vec4<f32>(0.0);
    var q_11 = query_chunk(i, q_at, 11u * LANES + lane);
    var o_11 = vec4<f32>(0.0);
    var q_12 = query_chunk(i, q_at, 12u * LANES + lane);
    var o_12 = vec4<f32>(0.0);
    var q_13 = query_chunk(i, q_at, 13u * LANES + lane);
    var o_13 = vec4<f32>(0.0);
    var q_14 = query_chunk(i, q_at, 14u * LANES + lane);
    var o_14 = vec4<f32>(0.0);
    var q_15 = query_chunk(i, q_at, 15u * LANES + lane);
    var o_15 = vec4<f32>(0.0);
    var q_16 = query_chunk(i, q_at, 16u * LANES + lane);
    var o_16 = vec4<f32>(0.0);
    var q_17 = query_chunk(i, q_at, 17u * LANES + lane);
    var o_17 = vec4<f32>(0.0);
    var q_18 = query_chunk(i, q_at, 18u * LANES + lane);
    var o_18 = vec4<f32>(0.0);
    var q_19 = query_chunk(i, q_at, 19u * LANES + lane);
    var o_19 = vec4<f32>(0.0);
    var q_20 = query_chunk(i, q_at, 20u * LANES + lane);
    var o_20 = vec4<f32>(0.0);
    var q_21 = query_chunk(i, q_at, 21u * LANES + lane);
    var o_21 = vec4<f32>(0.0);
    var q_22 = query_chunk(i, q_at, 22u * LANES + lane);
    var o_22 = vec4<f32>(0.0);
    var q_23 = query_chunk(i, q_at, 23u * LANES + lane);
    var o_23 = vec4<f32>(0.0);
    var q_24 = query_chunk(i, q_at, 24u * LANES + lane);
    var o_24 = vec4<f32>(0.0);
    var q_25 = query_chunk(i, q_at, 25u * LANES + lane);
    var o_25 = vec4<f32>(0.0);
    var q_26 = query_chunk(i, q_at, 26u * LANES + lane);
    var o_26 = vec4<f32>(0.0);
    var q_27 = query_chunk(i, q_at, 27u * LANES + lane);
    var o_27 = vec4<f32>(0.0);
    var q_28 = query_chunk(i, q_at, 28u * LANES + lane);
    var o_28 = vec4<f32>(0.0);
    var q_29 = query_chunk(i, q_at, 29u * LANES + lane);
    var o_29 = vec4<f32>(0.0);
    var q_30 = query_chunk(i, q_at, 30u * LANES + lane);
    var o_30 = vec4<f32>(0.0);
    var q_31 = query_chunk(i, q_at, 31u * LANES + lane);
    var o_31 = vec4<f32>(0.0);
    // END registers
    var m = NEG_BIG;
    var l = 0.0;
    for (var base = k0; base < k1; base += TILE_KEYS) {
        let n = min(TILE_KEYS, k1 - base);
        stage_keys(lid, h, base, n);
        workgroupBarrier();
        for (var j = 0u; j < n; j += 4u) {
            // Keys j .. j + 3 of the tile: their dot products with this lane's share of the query, a vec4 per
            // key; kb + g * CHUNKS + c is chunk c of key j + g.
            let kb = j * CHUNKS + lane;
            var dots_0 = vec4<f32>(0.0);
            var dots_1 = vec4<f32>(0.0);
            var dots_2 = vec4<f32>(0.0);
            var dots_3 = vec4<f32>(0.0);
            // BEGIN scores: written by tools/codegen/gen_attention.py
            dots_0 = fma(q_0, k_tile[kb + 0u * CHUNKS + 0u * LANES], dots_0);
            dots_1 = fma(q_0, k_tile[kb + 1u * CHUNKS + 0u * LANES], dots_1);
            dots_2 = fma(q_0, k_tile[kb + 2u * CHUNKS + 0u * LANES], dots_2);
            dots_3 = fma(q_0, k_tile[kb + 3u * CHUNKS + 0u * LANES], dots_3);
            dots_0 = fma(q_1, k_tile[kb + 0u * CHUNKS + 1u * LANES], dots_0);
            dots_1 = fma(q_1, k_tile[kb + 1u * CHUNKS + 1u * LANES], dots_1);
            dots_2 = fma(q_1, k_tile[kb + 2u * CHUNKS + 1u * LANES], dots_2);
            dots_3 = fma(q_1, k_tile[kb + 3u * CHUNKS + 1u * LANES], dots_3);
            if (REGS > 2u) {
                dots_0 = fma(q_2, k_tile[kb + 0u * CHUNKS + 2u * LANES], dots_0);
                dots_1 = fma(q_2, k_tile[kb + 1u * CHUNKS + 2u * LANES], dots_1);
                dots_2 = fma(q_2, k_tile[kb + 2u * CHUNKS + 2u * LANES], dots_2);
                dots_3 = fma(q_2, k_tile[kb + 3u * CHUNKS + 2u * LANES], dots_3);
                dots_0 = fma(q_3, k_tile[kb + 0u * CHUNKS + 3u * LANES], dots_0);
                dots_1 = fma(q_3, k_tile[kb + 1u * CHUNKS + 3u * LANES], dots_1);
                dots_2 = fma(q_3, k_tile[kb + 2u * CHUNKS + 3u * LANES], dots_2);
                dots_3 = fma(q_3, k_tile[kb + 3u * CHUNKS + 3u * LANES], dots_3);
            }
            if (REGS > 4u) {
                dots_0 = fma(q_4, k_tile[kb + 0u * CHUNKS + 4u * LANES], dots_0);
                dots_1 = fma(q_4, k_tile[kb + 1u * CHUNKS + 4u * LANES], dots_1);
                dots_2 = fma(q_4, k_tile[kb + 2u * CHUNKS + 4u * LANES], dots_2);
                dots_3 = fma(q_4, k_tile[kb + 3u * CHUNKS + 4u * LANES], dots_3);
                dots_0 = fma(q_5, k_tile[kb + 0u * CHUNKS + 5u * LANES], dots_0);
                dots_1 = fma(q_5, k_tile[kb + 1u * CHUNKS + 5u * LANES], dots_1);
                dots_2 = fma(q_5, k_tile[kb + 2u * CHUNKS + 5u * LANES], dots_2);
                dots_3 = fma(q_5, k_tile[kb + 3u * CHUNKS + 5u * LANES], dots_3);
                dots_0 = fma(q_6, k_tile[kb + 0u * CHUNKS + 6u * LANES], dots_0);
                dots_1 = fma(q_6, k_tile[kb + 1u * CHUNKS + 6u * LANES], dots_1);
                dots_2 = fma(q_6, k_tile[kb + 2u * CHUNKS + 6u * LANES], dots_2);
                dots_3 = fma(q_6, k_tile[kb + 3u * CHUNKS + 6u * LANES], dots_3);
                dots_0 = fma(q_7, k_tile[kb + 0u * CHUNKS + 7u * LANES], dots_0);
                dots_1 = fma(q_7, k_tile[kb + 1u * CHUNKS + 7u * LANES], dots_1);
                dots_2 = fma(q_7, k_tile[kb + 2u * CHUNKS + 7u * LANES], dots_2);
                dots_3 = fma(q_7, k_tile[kb + 3u * CHUNKS + 7u * LANES], dots_3);
            }
            if (REGS > 8u) {
                dots_0 = fma(q_8, k_tile[kb + 0u * CHUNKS + 8u * LANES], dots_0);
                dots_1 = fma(q_8, k_tile[kb + 1u * CHUNKS + 8u * LANES], dots_1);
                dots_2 = fma(q_8, k_tile[kb + 2u * CHUNKS + 8u * LANES], dots_2);
                dots_3 = fma(q_8, k_tile[kb + 3u * CHUNKS + 8u * LANES], dots_3);
                dots_0 = fma(q_9, k_tile[kb + 0u * CHUNKS + 9u * LANES], dots_0);
                dots_1 = fma(q_9, k_tile[kb + 1u * CHUNKS + 9u * LANES], dots_1);
                dots_2 = fma(q_9, k_tile[kb + 2u * CHUNKS + 9u * LANES], dots_2);
                dots_3 = fma(q_9, k_tile[kb + 3u * CHUNKS + 9u * LANES], dots_3);
                dots_0 = fma(q_10, k_tile[kb + 0u * CHUNKS + 10u * LANES], dots_0);
                dots_1 = fma(q_10, k_tile[kb + 1u * CHUNKS + 10u * LANES], dots_1);
                dots_2 = fma(q_10, k_tile[kb + 2u * CHUNKS + 10u * LANES], dots_2);
                dots_3 = fma(q_10, k_tile[kb + 3u * CHUNKS + 10u * LANES], dots_3);
                dots_0 = fma(q_11, k_tile[kb + 0u * CHUNKS + 11u * LANES], dots_0);
                dots_1 = fma(q_11, k_tile[kb + 1u * CHUNKS + 11u * LANES], dots_1);
                dots_2 = fma(q_11, k_tile[kb + 2u * CHUNKS + 11u * LANES], dots_2);
                dots_3 = fma(q_11, k_tile[kb + 3u * CHUNKS + 11u * LANES], dots_3);
                dots_0 = fma(q_12, k_tile[kb + 0u * CHUNKS + 12u * LANES], dots_0);
                dots_1 = fma(q_12, k_tile[kb + 1u * CHUNKS + 12u * LANES], dots_1);
                dots_2 = fma(q_12, k_tile[kb + 2u * CHUNKS + 12u * LANES], dots_2);
                dots_3 = fma(q_12, k_tile[kb + 3u * CHUNKS + 12u * LANES], dots_3);
                dots_0 = fma(q_13, k_tile[kb + 0u * CHUNKS + 13u * LANES], dots_0);
                dots_1 = fma(q_13, k_tile[kb + 1u * CHUNKS + 13u * LANES], dots_1);
                dots_2 = fma(q_13, k_tile[kb + 2u * CHUNKS + 13u * LANES], dots_2);
                dots_3 = fma(q_13, k_tile[kb + 3u * CHUNKS + 13u * LANES], dots_3);
                dots_0 = fma(q_14, k_tile[kb + 0u * CHUNKS + 14u * LANES], dots_0);
                dots_1 = fma(q_14, k_tile[kb + 1u * CHUNKS + 14u * LANES], dots_1);
                dots_2 = fma(q_14, k_tile[kb + 2u * CHUNKS + 14u * LANES], dots_2);
                dots_3 = fma(q_14, k_tile[kb + 3u * CHUNKS + 14u * LANES], dots_3);
                dots_0 = fma(q_15, k_tile[kb + 0u * CHUNKS + 15u * LANES], dots_0);
                dots_1 = fma(q_15, k_tile[kb + 1u * CHUNKS + 15u * LANES], dots_1);
                dots_2 = fma(q_15, k_tile[kb + 2u * CHUNKS + 15u * LANES], dots_2);
                dots_3 = fma(q_15, k_tile[kb + 3u * CHUNKS + 15u * LANES], dots_3);
            }
            if (REGS > 16u) {
                dots_0 = fma(q_16, k_tile[kb + 0u * CHUNKS + 16u * LANES], dots_0);
                dots_1 = fma(q_16, k_tile[kb + 1u * CHUNKS + 16u * LANES], dots_1);
                dots_2 = fma(q_16, k_tile[kb + 2u * CHUNKS + 16u * LANES], dots_2);
                dots_3 = fma(q_16, k_tile[kb + 3u * CHUNKS + 16u * LANES], dots_3);
                dots_0 = fma(q_17, k_tile[kb + 0u * CHUNKS + 17u * LANES], dots_0);
                dots_1 = fma(q_17, k_tile[kb + 1u * CHUNKS + 17u * LANES], dots_1);
                dots_2 = fma(q_17, k_tile[kb + 2u * CHUNKS + 17u * LANES], dots_2);
                dots_3 = fma(q_17, k_tile[kb + 3u * CHUNKS + 17u * LANES], dots_3);
                dots_0 = fma(q_18, k_tile[kb + 0u * CHUNKS + 18u * LANES], dots_0);
                dots_1 = fma(q_18, k_tile[kb + 1u * CHUNKS + 18u * LANES], dots_1);
                dots_2 = fma(q_18, k_tile[kb + 2u * CHUNKS + 18u * LANES], dots_2);
                dots_3 = fma(q_18, k_tile[kb + 3u * CHUNKS + 18u * LANES], dots_3);
                dots_0 = fma(q_19, k_tile[kb + 0u * CHUNKS + 19u * LANES], dots_0);
                dots_1 = fma(q_19, k_tile[kb + 1u * CHUNKS + 19u * LANES], dots_1);
                dots_2 = fma(q_19, k_tile[kb + 2u * CHUNKS + 19u * LANES], dots_2);
                dots_3 = fma(q_19, k_tile[kb + 3u * CHUNKS + 19u * LANES], dots_3);
                dots_0 = fma(q_20, k_tile[kb + 0u * CHUNKS + 20u * LANES], dots_0);
                dots_1 = fma(q_20, k_tile[kb + 1u * CHUNKS + 20u * LANES], dots_1);
                dots_2 = fma(q_20, k_tile[kb + 2u * CHUNKS + 20u * LANES], dots_2);
                dots_3 = fma(q_20, k_tile[kb + 3u * CHUNKS + 20u * LANES], dots_3);
                dots_0 = fma(q_21, k_tile[kb + 0u * CHUNKS + 21u * LANES], dots_0);
                dots_1 = fma(q_21, k_tile[kb + 1u * CHUNKS + 21u * LANES], dots_1);
                dots_2 = fma(q_21, k_tile[kb + 2u * CHUNKS + 21u * LANES], dots_2);
                dots_3 = fma(q_21, k_tile[kb + 3u * CHUNKS + 21u * LANES], dots_3);
                dots_0 = fma(q_22, k_tile[kb + 0u * CHUNKS + 22u * LANES], dots_0);
                dots_1 = fma(q_22, k_tile[kb + 1u * CHUNKS + 22u * LANES], dots_1);
                dots_2 = fma(q_22, k_tile[kb + 2u * CHUNKS + 22u * LANES], dots_2);
                dots_3 = fma(q_22, k_tile[kb + 3u * CHUNKS + 22u * LANES], dots_3);
                dots_0 = fma(q_23, k_tile[kb + 0u * CHUNKS + 23u * LANES], dots_0);
                dots_1 = fma(q_23, k_tile[kb + 1u * CHUNKS + 23u * LANES], dots_1);
                dots_2 = fma(q_23, k_tile[kb + 2u * CHUNKS + 23u * LANES], dots_2);
                dots_3 = fma(q_23, k_tile[kb + 3u * CHUNKS + 23u * LANES], dots_3);
                dots_0 = fma(q_24, k_tile[kb + 0u * CHUNKS + 24u * LANES], dots_0);
                dots_1 = fma(q_24, k_tile[kb + 1u * CHUNKS + 24u * LANES], dots_1);
                dots_2 = fma(q_24, k_tile[kb + 2u * CHUNKS + 24u * LANES], dots_2);
                dots_3 = fma(q_24, k_tile[kb + 3u * CHUNKS + 24u * LANES], dots_3);
                dots_0 = fma(q_25, k_tile[kb + 0u * CHUNKS + 25u * LANES], dots_0);
                dots_1 = fma(q_25, k_tile[kb + 1u * CHUNKS + 25u * LANES], dots_1);
                dots_2 = fma(q_25, k_tile[kb + 2u * CHUNKS + 25u * LANES], dots_2);
                dots_3 = fma(q_25, k_tile[kb + 3u * CHUNKS + 25u * LANES], dots_3);
                dots_0 = fma(q_26, k_tile[kb + 0u * CHUNKS + 26u * LANES], dots_0);
                dots_1 = fma(q_26, k_tile[kb + 1u * CHUNKS + 26u * LANES], dots_1);
                dots_2 = fma(q_26, k_tile[kb + 2u * CHUNKS + 26u * LANES], dots_2);
                dots_3 = fma(q_26, k_tile[kb + 3u * CHUNKS + 26u * LANES], dots_3);
                dots_0 = fma(q_27, k_tile[kb + 0u * CHUNKS + 27u * LANES], dots_0);
                dots_1 = fma(q_27, k_tile[kb + 1u * CHUNKS + 27u * LANES], dots_1);
                dots_2 = fma(q_27, k_tile[kb + 2u * CHUNKS + 27u * LANES], dots_2);
                dots_3 = fma(q_27, k_tile[kb + 3u * CHUNKS + 27u * LANES], dots_3);
                dots_0 = fma(q_28, k_tile[kb + 0u * CHUNKS + 28u * LANES], dots_0);
                dots_1 = fma(q_28, k_tile[kb + 1u * CHUNKS + 28u * LANES], dots_1);
                dots_2 = fma(q_28, k_tile[kb + 2u * CHUNKS + 28u * LANES], dots_2);
                dots_3 = fma(q_28, k_tile[kb + 3u * CHUNKS + 28u * LANES], dots_3);
                dots_0 = fma(q_29, k_tile[kb + 0u * CHUNKS + 29u * LANES], dots_0);
                dots_1 = fma(q_29, k_tile[kb + 1u * CHUNKS + 29u * LANES], dots_1);
                dots_2 = fma(q_29, k_tile[kb + 2u * CHUNKS + 29u * LANES], dots_2);
                dots_3 = fma(q_29, k_tile[kb + 3u * CHUNKS + 29u * LANES], dots_3);
                dots_0 = fma(q_30, k_tile[kb + 0u * CHUNKS + 30u * LANES], dots_0);
                dots_1 = fma(q_30, k_tile[kb + 1u * CHUNKS + 30u * LANES], dots_1);
                dots_2 = fma(q_30, k_tile[kb + 2u * CHUNKS + 30u * LANES], dots_2);
                dots_3 = fma(q_30, k_tile[kb + 3u * CHUNKS + 30u * LANES], dots_3);
                dots_0 = fma(q_31, k_tile[kb + 0u * CHUNKS + 31u * LANES], dots_0);
                dots_1 = fma(q_31, k_tile[kb + 1u * CHUNKS + 31u * LANES], dots_1);
                dots_2 = fma(q_31, k_tile[kb + 2u * CHUNKS + 31u * LANES], dots_2);
                dots_3 = fma(q_31, k_tile[kb + 3u * CHUNKS + 31u * LANES], dots_3);
            }
            // END scores
            let real = vec4<u32>(j) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(n);
            let scores = select(vec4<f32>(NEG_BIG), lanes_sum(vec4<f32>(
                (dots_0.x + dots_0.y) + (dots_0.z + dots_0.w), (dots_1.x + dots_1.y) + (dots_1.z + dots_1.w),
                (dots_2.x + dots_2.y) + (dots_2.z + dots_2.w), (dots_3.x + dots_3.y) + (dots_3.z + dots_3.w))), real);
            let m_new = max(m, max(max(scores.x, scores.y), max(scores.z, scores.w)));
            let corr = exp(m - m_new);
            let weights = exp(scores - m_new);
            l = l * corr + ((weights.x + weights.y) + (weights.z + weights.w));
            m = m_new;
            // BEGIN accumulate: written by tools/codegen/gen_attention.py
            o_0 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 0u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 0u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 0u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 0u * LANES], o_0 * corr))));
            o_1 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 1u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 1u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 1u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 1u * LANES], o_1 * corr))));
            if (REGS > 2u) {
                o_2 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 2u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 2u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 2u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 2u * LANES], o_2 * corr))));
                o_3 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 3u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 3u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 3u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 3u * LANES], o_3 * corr))));
            }
            if (REGS > 4u) {
                o_4 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 4u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 4u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 4u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 4u * LANES], o_4 * corr))));
                o_5 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 5u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 5u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 5u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 5u * LANES], o_5 * corr))));
                o_6 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 6u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 6u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 6u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 6u * LANES], o_6 * corr))));
                o_7 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 7u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 7u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 7u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 7u * LANES], o_7 * corr))));
            }
            if (REGS > 8u) {
                o_8 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 8u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 8u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 8u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 8u * LANES], o_8 * corr))));
                o_9 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 9u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 9u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 9u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 9u * LANES], o_9 * corr))));
                o_10 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 10u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 10u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 10u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 10u * LANES], o_10 * corr))));
                o_11 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 11u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 11u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 11u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 11u * LANES], o_11 * corr))));
                o_12 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 12u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 12u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 12u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 12u * LANES], o_12 * corr))));
                o_13 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 13u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 13u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 13u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 13u * LANES], o_13 * corr))));
                o_14 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 14u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 14u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 14u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 14u * LANES], o_14 * corr))));
                o_15 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 15u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 15u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 15u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 15u * LANES], o_15 * corr))));
            }
            if (REGS > 16u) {
                o_16 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 16u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 16u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 16u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 16u * LANES], o_16 * corr))));
                o_17 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 17u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 17u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 17u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 17u * LANES], o_17 * corr))));
                o_18 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 18u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 18u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 18u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 18u * LANES], o_18 * corr))));
                o_19 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 19u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 19u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 19u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 19u * LANES], o_19 * corr))));
                o_20 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 20u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 20u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 20u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 20u * LANES], o_20 * corr))));
                o_21 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 21u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 21u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 21u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 21u * LANES], o_21 * corr))));
                o_22 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 22u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 22u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 22u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 22u * LANES], o_22 * corr))));
                o_23 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 23u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 23u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 23u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 23u * LANES], o_23 * corr))));
                o_24 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 24u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 24u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 24u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 24u * LANES], o_24 * corr))));
                o_25 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 25u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 25u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 25u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 25u * LANES], o_25 * corr))));
                o_26 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 26u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 26u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 26u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 26u * LANES], o_26 * corr))));
                o_27 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 27u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 27u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 27u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 27u * LANES], o_27 * corr))));
                o_28 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 28u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 28u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 28u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 28u * LANES], o_28 * corr))));
                o_29 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 29u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 29u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 29u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 29u * LANES], o_29 * corr))));
                o_30 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 30u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 30u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 30u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 30u * LANES], o_30 * corr))));
                o_31 = fma(vec4<f32>(weights.w), v_tile[kb + 3u * CHUNKS + 31u * LANES], fma(vec4<f32>(weights.z), v_tile[kb + 2u * CHUNKS + 31u * LANES], fma(vec4<f32>(weights.y), v_tile[kb + 1u * CHUNKS + 31u * LANES], fma(vec4<f32>(weights.x), v_tile[kb + 0u * CHUNKS + 31u * LANES], o_31 * corr))));
            }
            // END accumulate
        }
        workgroupBarrier();
    }
    if (i >= p.nq) {
        return;
    }
    let dh = p.dim_head;
    // The row's m and l, and its padding, by its first lane.
    var at = i * p.out_ld + h * dh;
    var scale = 1.0 / l;
    if (p.splits > 1u) {
        at = (tile.split * p.nq + i) * p.partial_ld + h * (dh + 2u);
        scale = 1.0;
        if (lane == 0u) {
            out[at + dh] = m;
            out[at + dh + 1u] = l;
        }
    } else if (h + 1u == p.heads && lane == 0u) {
        // The row's padding, by the invocation of the last head.
        for (var c = p.heads * dh; c < p.out_ld; c++) {
            out[i * p.out_ld + c] = 0.0;
        }
    }
    // BEGIN store: written by tools/codegen/gen_attention.py
    store_chunk(at, 0u * LANES + lane, o_0 * scale);
    store_chunk(at, 1u * LANES + lane, o_1 * scale);
    if (REGS > 2u) {
        store_chunk(at, 2u * LANES + lane, o_2 * scale);
        store_chunk(at, 3u * LANES + lane, o_3 * scale);
    }
    if (REGS > 4u) {
        store_chunk(at, 4u * LANES + lane, o_4 * scale);
        store_chunk(at, 5u * LANES + lane, o_5 * scale);
        store_chunk(at, 6u * LANES + lane, o_6 * scale);
        store_chunk(at, 7u * LANES + lane, o_7 * scale);
    }
    if (REGS > 8u) {
        store_chunk(at, 8u * LANES + lane, o_8 * scale);
        store_chunk(at, 9u * LANES + lane, o_9 * scale);
        store_chunk(at, 10u * LANES + lane, o_10 * scale);
        store_chunk(at, 11u * LANES + lane, o_11 * scale);
        store_chunk(at, 12u * LANES + lane, o_12 * scale);
        store_chunk(at, 13u * LANES + lane, o_13 * scale);
        store_chunk(at, 14u * LANES + lane, o_14 * scale);
        store_chunk(at, 15u * LANES + lane, o_15 * scale);
    }
    if (REGS > 16u) {
        store_chunk(at, 16u * LANES + lane, o_16 * scale);
        store_chunk(at, 17u * LANES + lane, o_17 * scale);
        store_chunk(at, 18u * LANES + lane, o_18 * scale);
        store_chunk(at, 19u * LANES + lane, o_19 * scale);
        store_chunk(at, 20u * LANES + lane, o_20 * scale);
        store_chunk(at, 21u * LANES + lane, o_21 * scale);
        store_chunk(at, 22u * LANES + lane, o_22 * scale);
        store_chunk(at, 23u * LANES + lane, o_23 * scale);
        store_chunk(at, 24u * LANES + lane, o_24 * scale);
        store_chunk(at, 25u * LANES + lane, o_25 * scale);
        store_chunk(at, 26u * LANES + lane, o_26 * scale);
        store_chunk(at, 27u * LANES + lane, o_27 * scale);
        store_chunk(at, 28u * LANES + lane, o_28 * scale);
        store_chunk(at, 29u * LANES + lane, o_29 * scale);
        store_chunk(at, 30u * LANES + lane, o_30 * scale);
        store_chunk(at, 31u * LANES + lane, o_31 * scale);
    }
    // END store
}

// `combine`: the partials at binding 1, the output at binding 2; one invocation per float of the output (column c
// of query row i: float c % dim_head of head c / dim_head, or row padding), so that a (query, head)'s floats merge
// in parallel rather than one after another (300 queries x 12 heads are too few invocations to fill a GPU). Each
// takes its head's max over the splits, then its float and the head's sum in one pass (the reads of m and l are
// shared by the head's invocations through the cache).
@group(0) @binding(1) var<storage, read> partials: array<f32>;
@group(0) @binding(2) var<storage, read_write> combined: array<f32>;

// Invocations per workgroup of `combine` (kernels::attention::COMBINE_WG).
const COMBINE_WG: u32 = 64u;

@compute @workgroup_size(COMBINE_WG)
fn combine(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * COMBINE_WG + lid;
    if (index >= p.nq * p.out_ld) {
        return;
    }
    let i = index / p.out_ld;
    let c = index % p.out_ld;
    let dh = p.dim_head;
    if (c >= p.heads * dh) {
        combined[index] = 0.0;
        return;
    }
    let head = (c / dh) * (dh + 2u);
    let d = c % dh;
    var m = NEG_BIG;
    for (var s = 0u; s < p.splits; s++) {
        m = max(m, partials[(s * p.nq + i) * p.partial_ld + head + dh]);
    }
    var l = 0.0;
    var o = 0.0;
    for (var s = 0u; s < p.splits; s++) {
        let at = (s * p.nq + i) * p.partial_ld + head;
        let weight = exp(partials[at + dh] - m);
        l += weight * partials[at + dh + 1u];
        o += weight * partials[at + d];
    }
    combined[index] = o / l;
}
