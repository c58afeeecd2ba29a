// `attention_coop` (MatmulKernel::Coop): flash attention with both products on f16 cooperative matrices and the
// online softmax in f32 between them: out[i, h*dh ..] = Σ_j softmax_j(scale · q_i,h · k_j,h) · v_j,h.
//
// Work split, as attention_flash.wgsl's: a workgroup serves one (query tile, head, key split); with several splits
// each writes its unnormalised output with its running max m and sum l to the partials, and attention_flash's
// `combine` merges them. A query tile is CT rows (the adapter's cooperative-matrix size, coop_size.wgsl, a prelude
// before attention_params.wgsl and this file); the keys go COOP_SUBGROUPS·CT at a time (a key block), one CT-wide
// column of them per subgroup. The head is padded with zeros to COOP_DH floats (a multiple of COOP_SUBGROUPS·CT, an
// override constant per op), so that every subgroup has the same number of output blocks.
//
// Per key block, with a barrier between the steps:
//   1. stage the block's keys (f16, zeros past the split or the head);
//   2. S = Q · Kᵀ: subgroup s its CT x CT block of scores (keys s·CT ..), summed over the head in f32, to `sp`;
//   3. each row's block max, over WG / CT invocations a row; the block's values are staged where the keys were;
//   4. the new max m, P = exp(scale·S − m) (f32, rounded to f16 for the product) and each row's share of Σ P;
//   5. the row's new l and the rescale of its output, exp(m_old − m); P · V in cooperative matrices, subgroup s
//      its output blocks s, s + COOP_SUBGROUPS, .., to `sp`;
//   6. O = O · rescale + P · V, in f32, in workgroup memory.
// Numbers: q, k, v and P rounded to f16 as they are staged, the scores, the softmax and the sums in f32.

// The adapter's subgroup width, and the head padded (kernels::attention).
override COOP_LANES: u32 = 32u;
override COOP_DH: u32 = 64u;
const COOP_SUBGROUPS: u32 = 4u;
override WG: u32 = COOP_SUBGROUPS * COOP_LANES;
// Keys per block, the row strides of the staged f16 operands (padded by 8 halves: 16 bytes), invocations a row.
const BC: u32 = COOP_SUBGROUPS * CT;
override QK_LD: u32 = COOP_DH + 8u;
const P_LD: u32 = BC + 8u;
override ROW_LANES: u32 = WG / CT;
override Q_HALVES: u32 = CT * QK_LD;
override KV_HALVES: u32 = BC * QK_LD;
// `sp` holds the scores (CT x BC), then P · V (CT x COOP_DH; COOP_DH >= BC).
override SP_FLOATS: u32 = CT * COOP_DH;
override O_FLOATS: u32 = CT * COOP_DH;
override RED_FLOATS: u32 = CT * ROW_LANES;
// Stands for -inf: the running max before the first key and the score of a key past the split (exp(NEG_BIG - m)
// is 0 for a real m; every block holds a real key).
const NEG_BIG: f32 = -3.0e38;

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> q: array<f32>;
@group(0) @binding(2) var<storage, read> k: array<f32>;
@group(0) @binding(3) var<storage, read> v: array<f32>;
// One split: the output [nq, out_ld]. Several: the partials [splits * nq, partial_ld], row s*nq + i holding
// head h's unnormalised output at h*(dim_head + 2), then its m and l (attention_flash.wgsl's layout).
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

var<workgroup> q_tile: array<f16, Q_HALVES>;
var<workgroup> kv_tile: array<f16, KV_HALVES>;
var<workgroup> p_tile: array<f16, CT * P_LD>;
var<workgroup> sp: array<f32, SP_FLOATS>;
var<workgroup> o_tile: array<f32, O_FLOATS>;
var<workgroup> red: array<f32, RED_FLOATS>;
// Per query row: the running max and sum, and the rescale of the output for the current block.
var<workgroup> row_m: array<f32, CT>;
var<workgroup> row_l: array<f32, CT>;
var<workgroup> row_scale: array<f32, CT>;

// Stages key (`keys`) or value rows base .. base + n of head h into kv_tile: zeros past n and the head.
fn stage_kv(keys: bool, li: u32, h: u32, base: u32, n: u32) {
    for (var i = li; i < BC * COOP_DH; i += WG) {
        let j = i / COOP_DH;
        let d = i % COOP_DH;
        var x = 0.0;
        if (j < n && d < p.dim_head) {
            if (keys) {
                x = k[(base + j) * p.k_ld + p.k_col + h * p.dim_head + d];
            } else {
                x = v[(base + j) * p.v_ld + p.v_col + h * p.dim_head + d];
            }
        }
        kv_tile[j * QK_LD + d] = f16(x);
    }
}

@compute @workgroup_size(WG)
fn attention_coop(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) li: u32, @builtin(subgroup_id) sg_id: u32) {
    let g = wid.x + wid.y * nwg.x;
    let rest = g / p.query_tiles;
    let first_row = (g % p.query_tiles) * CT;
    let h = rest % p.heads;
    let split = rest / p.heads;
    // The same for the whole workgroup, so the barriers and cooperative operations stay in uniform control flow.
    if (split >= p.splits) {
        return;
    }
    let sg = min(sg_id, COOP_SUBGROUPS - 1u);
    let key_begin = split * p.split_keys;
    let key_end = min(p.nkv, key_begin + p.split_keys);
    let dh = p.dim_head;
    for (var i = li; i < CT * COOP_DH; i += WG) {
        let r = i / COOP_DH;
        let d = i % COOP_DH;
        var x = 0.0;
        if (first_row + r < p.nq && d < dh) {
            x = q[(first_row + r) * p.q_ld + p.q_col + h * dh + d];
        }
        q_tile[r * QK_LD + d] = f16(x);
        o_tile[i] = 0.0;
    }
    if (li < CT) {
        row_m[li] = NEG_BIG;
        row_l[li] = 0.0;
    }
    // This invocation's share of the softmax: row `row`, columns col0 .. col0 + BC / ROW_LANES of the block.
    let row = li / ROW_LANES;
    let part = li % ROW_LANES;
    let cols = BC / ROW_LANES;
    let col0 = part * cols;
    for (var base = key_begin; base < key_end; base += BC) {
        let n = min(BC, key_end - base);
        stage_kv(true, li, h, base, n);
        workgroupBarrier();
        var s = CoopC();
        for (var d0 = 0u; d0 < COOP_DH; d0 += CT) {
            let q_at = d0;
            let k_at = sg * CT * QK_LD + d0;
            let a = coopLoadT<CoopA>(&q_tile[q_at], QK_LD);
            let b = coopLoad<CoopB>(&kv_tile[k_at], QK_LD);
            s = coopMultiplyAdd(a, b, s);
        }
        let s_at = sg * CT;
        coopStoreT(s, &sp[s_at], BC);
        workgroupBarrier();
        var block_max = NEG_BIG;
        for (var c = col0; c < col0 + cols; c++) {
            if (c < n) {
                block_max = max(block_max, p.scale * sp[row * BC + c]);
            }
        }
        red[li] = block_max;
        stage_kv(false, li, h, base, n);
        workgroupBarrier();
        var m_new = row_m[row];
        for (var j = 0u; j < ROW_LANES; j++) {
            m_new = max(m_new, red[row * ROW_LANES + j]);
        }
        var sum = 0.0;
        for (var c = col0; c < col0 + cols; c++) {
            var e = 0.0;
            if (c < n) {
                e = exp(p.scale * sp[row * BC + c] - m_new);
            }
            p_tile[row * P_LD + c] = f16(e);
            sum += e;
        }
        workgroupBarrier();
        red[li] = sum;
        workgroupBarrier();
        if (part == 0u) {
            let rescale = exp(row_m[row] - m_new);
            var l = row_l[row] * rescale;
            for (var j = 0u; j < ROW_LANES; j++) {
                l += red[row * ROW_LANES + j];
            }
            row_l[row] = l;
            row_m[row] = m_new;
            row_scale[row] = rescale;
        }
        // COOP_DH / CT is a multiple of COOP_SUBGROUPS: the same count for every subgroup (uniform control flow).
        for (var fi = 0u; fi < COOP_DH / CT / COOP_SUBGROUPS; fi++) {
            let f = fi * COOP_SUBGROUPS + sg;
            var o = CoopC();
            for (var c0 = 0u; c0 < BC; c0 += CT) {
                let p_at = c0;
                let v_at = c0 * QK_LD + f * CT;
                let a = coopLoadT<CoopA>(&p_tile[p_at], P_LD);
                let b = coopLoadT<CoopB>(&kv_tile[v_at], QK_LD);
                o = coopMultiplyAdd(a, b, o);
            }
            let o_at = f * CT;
            coopStoreT(o, &sp[o_at], COOP_DH);
        }
        workgroupBarrier();
        for (var i = li; i < CT * COOP_DH; i += WG) {
            o_tile[i] = o_tile[i] * row_scale[i / COOP_DH] + sp[i];
        }
        workgroupBarrier();
    }
    // The output: normalised, or raw with m and l into the split's partials.
    for (var i = li; i < CT * COOP_DH; i += WG) {
        let r = i / COOP_DH;
        let d = i % COOP_DH;
        let qi = first_row + r;
        if (qi >= p.nq || d >= dh) {
            continue;
        }
        if (p.splits == 1u) {
            out[qi * p.out_ld + h * dh + d] = o_tile[i] / row_l[r];
        } else {
            let at = (split * p.nq + qi) * p.partial_ld + h * (dh + 2u);
            out[at + d] = o_tile[i];
            if (d == 0u) {
                out[at + dh] = row_m[r];
                out[at + dh + 1u] = row_l[r];
            }
        }
    }
    // The row padding of the output, by the last head's workgroup.
    if (p.splits == 1u && h == p.heads - 1u) {
        let pad = p.out_ld - p.heads * dh;
        for (var i = li; i < CT * pad; i += WG) {
            let qi = first_row + i / pad;
            if (qi < p.nq) {
                out[qi * p.out_ld + p.heads * dh + i % pad] = 0.0;
            }
        }
    }
}
