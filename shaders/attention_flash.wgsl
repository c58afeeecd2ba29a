// Multi-head attention for GPUs, flash-attention style: out[i, h*dh ..] = Σ_j softmax_j(scale · q_i,h · k_j,h) · v_j,h.
//
// Work split (FlashAttention-2, with flash-decoding's split of the keys): a workgroup of 64 invocations serves
// one (query tile of 64 rows, head, key split). Each invocation owns one query row: its scaled query and its
// output accumulator stay in registers (CHUNKS vec4s each, CHUNKS fixed per variant so that every loop has a
// constant trip count), with a running max m and sum l (online softmax: the nq x nkv scores never exist).
// The keys and values of the split go through workgroup memory a tile of TILE_KEYS keys at a time, loaded
// cooperatively (consecutive invocations read consecutive floats of a key row) and then read by every
// invocation at the same address (a broadcast). Per tile an invocation computes its TILE_KEYS scores, takes
// their max, rescales its accumulator once, and adds the weighted values.
//
// When queries x heads give too few workgroups to fill a GPU (a Ray-Patch render has 300 queries: 5 tiles a
// head), the wrapper splits the keys: each split writes its unnormalised output with its m and l to the
// partials (`flash_split`), and `combine` merges the splits of each (query, head) exactly as the online
// softmax would: M = max m_s, out = Σ e^(m_s - M) o_s / Σ e^(m_s - M) l_s. With one split `flash` writes
// the output itself.
//
// Operands are read as floats, so heads may start at any column (fused qkv tensors, odd dim_head); a head's
// floats past dim_head are zeros in the tiles and registers. Output rows are written whole: the last head's
// invocation zeroes the row padding.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> q: array<f32>;
@group(0) @binding(2) var<storage, read> k: array<f32>;
@group(0) @binding(3) var<storage, read> v: array<f32>;
// `flash`: the output [nq, out_ld]; `flash_split`: the partials [splits * nq, partial_ld], row s*nq + i holding
// head h's unnormalised output at h*(dim_head + 2), then its m and l.
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

const WG: u32 = 64u;
// vec4s per head in registers: dim_head <= 4 * CHUNKS. 32 here; the wrapper's variants replace it by 16 and 8.
const CHUNKS: u32 = 32u;
// vec4s of keys (and as many of values) per tile: 2 x 8 KiB, within WebGPU's guaranteed 16 KiB.
const TILE_VEC4S: u32 = 512u;
const TILE_KEYS: u32 = TILE_VEC4S / CHUNKS;
// Stands for -inf: the running max before the first key and the score of a key past the split. exp(NEG_BIG - m)
// is 0 for any real m, and every tile holds at least one real key.
const NEG_BIG: f32 = -3.0e38;

var<workgroup> k_tile: array<vec4<f32>, TILE_VEC4S>;
var<workgroup> v_tile: array<vec4<f32>, TILE_VEC4S>;

// One invocation's query row, its softmax state and its output.
struct Row {
    m: f32,
    l: f32,
    o: array<vec4<f32>, CHUNKS>,
}

// The attention of query row `i` (if `i < nq`) of head `h` over keys k0 .. k1, with the workgroup.
fn attend(lid: u32, i: u32, h: u32, k0: u32, k1: u32) -> Row {
    let dh = p.dim_head;
    var qs: array<vec4<f32>, CHUNKS>;
    var row: Row;
    row.m = NEG_BIG;
    row.l = 0.0;
    let q_at = i * p.q_ld + p.q_col + h * dh;
    for (var c = 0u; c < CHUNKS; c++) {
        var chunk = vec4<f32>(0.0);
        for (var e = 0u; e < 4u; e++) {
            let d = 4u * c + e;
            if (i < p.nq && d < dh) {
                chunk[e] = q[q_at + d];
            }
        }
        qs[c] = p.scale * chunk;
        row.o[c] = vec4<f32>(0.0);
    }
    for (var base = k0; base < k1; base += TILE_KEYS) {
        let n = min(TILE_KEYS, k1 - base);
        // Slot s of a tile holds chunk s % CHUNKS of key s / CHUNKS (zeros past the head or the split).
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
        workgroupBarrier();
        var s: array<f32, TILE_KEYS>;
        var m_tile = NEG_BIG;
        for (var j = 0u; j < TILE_KEYS; j++) {
            var score = NEG_BIG;
            if (j < n) {
                var acc = vec4<f32>(0.0);
                for (var c = 0u; c < CHUNKS; c++) {
                    acc += qs[c] * k_tile[j * CHUNKS + c];
                }
                score = (acc.x + acc.y) + (acc.z + acc.w);
            }
            s[j] = score;
            m_tile = max(m_tile, score);
        }
        let m_new = max(row.m, m_tile);
        let corr = exp(row.m - m_new);
        row.l *= corr;
        for (var c = 0u; c < CHUNKS; c++) {
            row.o[c] *= corr;
        }
        for (var j = 0u; j < TILE_KEYS; j++) {
            let weight = exp(s[j] - m_new);
            row.l += weight;
            for (var c = 0u; c < CHUNKS; c++) {
                row.o[c] += weight * v_tile[j * CHUNKS + c];
            }
        }
        row.m = m_new;
        workgroupBarrier();
    }
    return row;
}

// The (query tile, head, key split) of a workgroup, and whether it has one (the grid may have more groups).
// Uniform across the workgroup, as the barriers in `attend` need.
struct Tile {
    first_row: u32,
    h: u32,
    split: u32,
    valid: bool,
}

fn tile_of(wid: vec3<u32>, nwg: vec3<u32>) -> Tile {
    let g = wid.x + wid.y * nwg.x;
    let rest = g / p.query_tiles;
    return Tile((g % p.query_tiles) * WG, rest % p.heads, rest / p.heads, rest < p.heads * p.splits);
}

// Writes a head's dim_head floats of `o`, times `scale`, at `at` of `out`.
fn store_head(at: u32, o: array<vec4<f32>, CHUNKS>, scale: f32) {
    for (var c = 0u; c < CHUNKS; c++) {
        for (var e = 0u; e < 4u; e++) {
            let d = 4u * c + e;
            if (d < p.dim_head) {
                out[at + d] = o[c][e] * scale;
            }
        }
    }
}

// Zeroes the padding of output row i (by the invocation of the last head).
fn zero_padding(i: u32, h: u32) {
    if (h + 1u == p.heads) {
        for (var c = p.heads * p.dim_head; c < p.out_ld; c++) {
            out[i * p.out_ld + c] = 0.0;
        }
    }
}

@compute @workgroup_size(64)
fn flash(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let tile = tile_of(wid, nwg);
    if (!tile.valid) {
        return; // the whole workgroup
    }
    let i = tile.first_row + lid;
    let row = attend(lid, i, tile.h, 0u, p.nkv);
    if (i >= p.nq) {
        return;
    }
    store_head(i * p.out_ld + tile.h * p.dim_head, row.o, 1.0 / row.l);
    zero_padding(i, tile.h);
}

@compute @workgroup_size(64)
fn flash_split(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let tile = tile_of(wid, nwg);
    if (!tile.valid) {
        return; // the whole workgroup
    }
    let i = tile.first_row + lid;
    let k0 = tile.split * p.split_keys;
    let row = attend(lid, i, tile.h, k0, min(p.nkv, k0 + p.split_keys));
    if (i >= p.nq) {
        return;
    }
    let dh = p.dim_head;
    let at = (tile.split * p.nq + i) * p.partial_ld + tile.h * (dh + 2u);
    store_head(at, row.o, 1.0);
    out[at + dh] = row.m;
    out[at + dh + 1u] = row.l;
}

// `combine`: the partials at binding 1, the output at binding 2; one invocation per float of the output (column c
// of query row i: float c % dim_head of head c / dim_head, or row padding), so that a (query, head)'s floats merge
// in parallel rather than one after another (300 queries x 12 heads are too few invocations to fill a GPU). Each
// takes its head's max over the splits, then its float and the head's sum in one pass (the reads of m and l are
// shared by the head's invocations through the cache).
@group(0) @binding(1) var<storage, read> partials: array<f32>;
@group(0) @binding(2) var<storage, read_write> combined: array<f32>;

@compute @workgroup_size(64)
fn combine(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * WG + lid;
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
