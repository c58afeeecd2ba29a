// Fused multi-head attention: out[i, h*dh ..] = Σ_j softmax_j(scale · q_i,h · k_j,h) · v_j,h.
//
// Softmax is online: a running max m and sum l per (query, head) and the output accumulator o, rescaled by
// exp(m_old - m_new) at every step of 4 keys (branch-free: the factor is 1 unless the max grew), so the
// nq x nkv score matrix never exists.
//
// Layout of the work: a workgroup serves one head and 64 * QUERIES consecutive query rows; each invocation
// owns QUERIES = 8 consecutive rows as two quads (a, b) of 4. Keys go 4 at a time: for each 4-float chunk
// of the head, a 4x4 matrix product gives the 16 scores of one quad with 4 keys, so each key/value chunk
// loaded serves 8 queries. On lavapipe every memory access with a computed index (storage buffers and
// dynamically indexed private arrays alike) is emulated lane by lane, while arithmetic runs 8 lanes wide:
// accesses per multiply-add decide the speed. Measured there, this tile is ~3x faster than one query per
// invocation; 4 or 16 queries, or 8 keys per step, were slower.
//
// Matrices are column-major: `kc[b]` is key b's chunk, `qa[c][d]` holds dimension 4c+d of the 4 queries
// of quad a, `s[b][t]` is the score of key b for query t, `oa[c][t]` is chunk c of query t's output.
//
// Column offsets need not be multiples of 4 (fused qkv tensors, odd dim_head), but every row starts
// 16-byte aligned: tensors are bound as vec4 arrays and each head chunk is realigned from two aligned vec4s
// by the head's misalignment r (the same for every row); the second vec4 is the first of the next chunk.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> q: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> k: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

const WG: u32 = 64u;
// Query rows per invocation (two quads).
const QUERIES: u32 = 8u;
// dim_head <= 128: a head is at most 32 chunks of 4.
const MAX_CHUNKS: u32 = 32u;
// Stands for -inf: the running max before the first key, and the score of a key past nkv. exp(NEG_BIG - m)
// is 0 for any real logit m, and every step has at least one real key, so m itself is always real.
const NEG_BIG: f32 = -3.0e38;
const LANE: vec4<u32> = vec4<u32>(0u, 1u, 2u, 3u);

// The aligned vec4s at vec4 indices `at` of 4 rows, as columns.
fn q_rows(at: vec4<u32>) -> mat4x4<f32> {
    return mat4x4<f32>(q[at.x], q[at.y], q[at.z], q[at.w]);
}
fn k_rows(at: vec4<u32>) -> mat4x4<f32> {
    return mat4x4<f32>(k[at.x], k[at.y], k[at.z], k[at.w]);
}
fn v_rows(at: vec4<u32>) -> mat4x4<f32> {
    return mat4x4<f32>(v[at.x], v[at.y], v[at.z], v[at.w]);
}

// The 4 floats that start r floats into a (r < 4) and continue into b.
fn realign(a: vec4<f32>, b: vec4<f32>, r: u32) -> vec4<f32> {
    let r1 = vec4<f32>(a.yzw, b.x);
    let r2 = vec4<f32>(a.zw, b.xy);
    let r3 = vec4<f32>(a.w, b.xyz);
    return select(select(select(r3, r2, r == 2u), r1, r == 1u), a, r == 0u);
}

fn realign_columns(a: mat4x4<f32>, b: mat4x4<f32>, r: u32) -> mat4x4<f32> {
    return mat4x4<f32>(realign(a[0], b[0], r), realign(a[1], b[1], r), realign(a[2], b[2], r), realign(a[3], b[3], r));
}

// Zeroes the rows >= n of every column (the floats past the end of the head in its last chunk).
fn mask_rows(m: mat4x4<f32>, n: u32) -> mat4x4<f32> {
    let keep = LANE < vec4<u32>(n);
    let zero = vec4<f32>(0.0);
    return mat4x4<f32>(select(zero, m[0], keep), select(zero, m[1], keep), select(zero, m[2], keep), select(zero, m[3], keep));
}

// Running softmax of 4 queries (one per vector lane).
struct Softmax {
    m: vec4<f32>,
    l: vec4<f32>,
}

// One step of 4 keys.
struct Weights {
    // Column t: the weights exp(s - m_new) of the 4 keys for query t.
    pt: mat4x4<f32>,
    // exp(m_old - m_new) per query: the factor for what was accumulated before this step.
    corr: vec4<f32>,
}

// Folds the scores s (s[b][t]: key b, query t; keys past nkv already NEG_BIG) into the running state.
fn softmax_step(state: ptr<function, Softmax>, s: mat4x4<f32>) -> Weights {
    let m_new = max((*state).m, max(max(s[0], s[1]), max(s[2], s[3])));
    let corr = exp((*state).m - m_new);
    let e = mat4x4<f32>(exp(s[0] - m_new), exp(s[1] - m_new), exp(s[2] - m_new), exp(s[3] - m_new));
    (*state).m = m_new;
    (*state).l = (*state).l * corr + ((e[0] + e[1]) + (e[2] + e[3]));
    return Weights(transpose(e), corr);
}

// The output update of one chunk: o * corr (per query column) + v chunk · weights.
fn accumulate(o: mat4x4<f32>, vc: mat4x4<f32>, w: Weights) -> mat4x4<f32> {
    return mat4x4<f32>(o[0] * w.corr.x, o[1] * w.corr.y, o[2] * w.corr.z, o[3] * w.corr.w) + vc * w.pt;
}

// The scaled chunks of 4 query rows starting at vec4 indices `at` (misalignment r), in qs[c][d][t] form.
fn load_queries(qs: ptr<function, array<mat4x4<f32>, MAX_CHUNKS>>, at: vec4<u32>, r: u32) {
    let dh = p.dim_head;
    var prev = q_rows(at);
    for (var c = 0u; c < (dh + 3u) / 4u; c++) {
        let next = q_rows(at + c + 1u);
        (*qs)[c] = transpose(p.scale * mask_rows(realign_columns(prev, next, r), dh - 4u * c));
        prev = next;
    }
}

// Writes out rows row0 .. row0+3 (those < nq) of the head: o / l, and the row padding after the last head.
fn store_queries(o: ptr<function, array<mat4x4<f32>, MAX_CHUNKS>>, state: Softmax, row0: u32, head: u32) {
    let dh = p.dim_head;
    for (var t = 0u; t < 4u && row0 + t < p.nq; t++) {
        let out_row = (row0 + t) * p.out_ld;
        let inv = 1.0 / state.l[t];
        for (var d = 0u; d < dh; d++) {
            out[out_row + head * dh + d] = (*o)[d / 4u][t][d % 4u] * inv;
        }
        if head + 1u == p.heads {
            for (var col = p.heads * dh; col < p.out_ld; col++) {
                out[out_row + col] = 0.0;
            }
        }
    }
}

@compute @workgroup_size(64)
fn attention(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let blocks = (p.nq + WG * QUERIES - 1u) / (WG * QUERIES);
    let group = wid.x + wid.y * nwg.x;
    if group >= blocks * p.heads {
        return;
    }
    let head = group / blocks;
    let row0 = ((group % blocks) * WG + lid) * QUERIES;
    if row0 >= p.nq {
        return;
    }
    let dh = p.dim_head;
    let chunks = (dh + 3u) / 4u;

    // Rows past nq repeat the last row; they are computed but not stored.
    let q_at = p.q_col + head * dh;
    let rows_a = min(vec4<u32>(row0) + LANE, vec4<u32>(p.nq - 1u));
    let rows_b = min(vec4<u32>(row0 + 4u) + LANE, vec4<u32>(p.nq - 1u));
    var qa: array<mat4x4<f32>, MAX_CHUNKS>;
    var qb: array<mat4x4<f32>, MAX_CHUNKS>;
    load_queries(&qa, (rows_a * p.q_ld + q_at) / 4u, q_at % 4u);
    load_queries(&qb, (rows_b * p.q_ld + q_at) / 4u, q_at % 4u);

    var oa: array<mat4x4<f32>, MAX_CHUNKS>;
    var ob: array<mat4x4<f32>, MAX_CHUNKS>;
    var sa = Softmax(vec4<f32>(NEG_BIG), vec4<f32>(0.0));
    var sb = Softmax(vec4<f32>(NEG_BIG), vec4<f32>(0.0));
    let k_at = p.k_col + head * dh;
    let v_at = p.v_col + head * dh;
    for (var j = 0u; j < p.nkv; j += 4u) {
        // Keys past nkv read the last row (in range) and get score NEG_BIG, i.e. weight 0.
        let keys = vec4<u32>(j) + LANE;
        let rows = min(keys, vec4<u32>(p.nkv - 1u));

        let kr = (rows * p.k_ld + k_at) / 4u;
        var k_prev = k_rows(kr);
        var scores_a = mat4x4<f32>();
        var scores_b = mat4x4<f32>();
        for (var c = 0u; c < chunks; c++) {
            let k_next = k_rows(kr + c + 1u);
            let kc = mask_rows(realign_columns(k_prev, k_next, k_at % 4u), dh - 4u * c);
            k_prev = k_next;
            scores_a += qa[c] * kc;
            scores_b += qb[c] * kc;
        }
        let valid = keys < vec4<u32>(p.nkv);
        let neg = vec4<f32>(NEG_BIG);
        let wa = softmax_step(&sa, mat4x4<f32>(
            select(neg, scores_a[0], valid.x), select(neg, scores_a[1], valid.y),
            select(neg, scores_a[2], valid.z), select(neg, scores_a[3], valid.w)));
        let wb = softmax_step(&sb, mat4x4<f32>(
            select(neg, scores_b[0], valid.x), select(neg, scores_b[1], valid.y),
            select(neg, scores_b[2], valid.z), select(neg, scores_b[3], valid.w)));

        // Value floats past the head only reach accumulator rows that are never stored.
        let vr = (rows * p.v_ld + v_at) / 4u;
        var v_prev = v_rows(vr);
        for (var c = 0u; c < chunks; c++) {
            let v_next = v_rows(vr + c + 1u);
            let vc = realign_columns(v_prev, v_next, v_at % 4u);
            v_prev = v_next;
            oa[c] = accumulate(oa[c], vc, wa);
            ob[c] = accumulate(ob[c], vc, wb);
        }
    }

    store_queries(&oa, sa, row0, head);
    store_queries(&ob, sb, row0 + 4u, head);
}
