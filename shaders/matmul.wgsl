// Linear layer: out = act(x · wᵀ + bias), or out += act(x · wᵀ + bias) when accumulating, in two kernels
// that compute the same sums: `linear` (register tiles; kernels::matmul::MatmulKernel::Rows) and
// `linear_tiled` (workgroup-memory tiles, for GPUs; MatmulKernel::Tiled), below it.
//
// x: [M, K] rows, w: [N, K] rows (nn.Linear layout), both padded with zeros to whole vec4s, so the K loop
// runs over whole vec4s. w is f32, or f16 in the matmul_f16 variant (kernels/mod.rs replaces the WeightVec
// alias below), widened to f32 as it is loaded: the arithmetic is f32 either way.
//
// `linear`: each invocation computes a 4x8 block of out: per vec4 step along K it loads 4 vec4s of x
// (4 rows) and 8 of w (8 rows) and takes 32 dot products; the block is written back as two vec4s per row,
// padding columns included (as zeros).
//
// Why 4x8: lavapipe (Mesa 25.0) turns every storage-buffer load inside a loop into a per-invocation
// scalar loop with bounds checks, uniform address or not, so loads cost far more than arithmetic and the
// block should carry as many outputs per loaded vec4 as registers allow. 4x8 and 8x4 measured fastest;
// 4x4 was ~10-15% slower, 8x8 ~30% slower (it spills), a 2-D 8x8 workgroup layout ~20% slower.
//
// Grid: a workgroup is 64 invocations stacked along M (256 rows) sharing one 8-column tile of w.
// Groups are numbered tile-fastest, so consecutive groups reuse the same rows of x.

struct Params {
    m: u32,
    n: u32,
    // ld(K) / 4: vec4s per row of x and w.
    k4: u32,
    // ld(N) / 4: vec4s per row of out.
    n4: u32,
    // 0 none, 1 relu, 2 leaky relu (slope), 3 gelu (erf form).
    act: u32,
    slope: f32,
    has_bias: u32,
    accumulate: u32,
    // vec4s per row of w: k4 for f32 weights; f16 rows are padded to 8 halves, so k4 or k4 + 1.
    w_ld4: u32,
    // `linear_tiled` only: K cut into `splits` ranges of k_split4 vec4s (a multiple of TILE_K4), one per
    // workgroup, when the output's tiles are too few to fill a GPU; m_tiles = ceil(m / TILE).
    splits: u32,
    k_split4: u32,
    m_tiles: u32,
    // `linear_tiled` only: 1 when x's rows are layer-normalised as they are staged (their statistics at binding
    // 7, gamma and beta at 5 and 6), else 0.
    norm: u32,
}

alias WeightVec = vec4<f32>;

@group(0) @binding(0) var<uniform> p: Params;

// Layer shapes fixed per pipeline (device::fixed_shapes: `linear_tiled` and `linear_reduce` on GPUs): with
// SHAPED, a layer's columns, depth, weight stride and flags are these override constants
// (kernels::matmul::fixed_shape), so the GPU's compiler sees strides and branches as constants and compiles the
// unused prologue and epilogue away; without, they come from the params (the same names). The row count and the
// K split, which change with every view count, size, region and band, always come from the params: one
// pipeline serves a layer at every size.
override SHAPED: bool = false;
override SHAPED_N: u32 = 0u;
override SHAPED_K4: u32 = 0u;
override SHAPED_N4: u32 = 0u;
override SHAPED_ACT: u32 = 0u;
override SHAPED_HAS_BIAS: u32 = 0u;
override SHAPED_ACCUMULATE: u32 = 0u;
override SHAPED_W_LD4: u32 = 0u;
override SHAPED_NORM: u32 = 0u;
fn op_m() -> u32 { return p.m; }
fn op_n() -> u32 { return select(p.n, SHAPED_N, SHAPED); }
fn op_k4() -> u32 { return select(p.k4, SHAPED_K4, SHAPED); }
fn op_n4() -> u32 { return select(p.n4, SHAPED_N4, SHAPED); }
fn op_act() -> u32 { return select(p.act, SHAPED_ACT, SHAPED); }
fn op_has_bias() -> u32 { return select(p.has_bias, SHAPED_HAS_BIAS, SHAPED); }
fn op_accumulate() -> u32 { return select(p.accumulate, SHAPED_ACCUMULATE, SHAPED); }
fn op_w_ld4() -> u32 { return select(p.w_ld4, SHAPED_W_LD4, SHAPED); }
fn op_splits() -> u32 { return p.splits; }
fn op_k_split4() -> u32 { return p.k_split4; }
fn op_m_tiles() -> u32 { return p.m_tiles; }
fn op_norm() -> u32 { return select(p.norm, SHAPED_NORM, SHAPED); }

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> w: array<WeightVec>;
// [1, N]; when there is no bias the wrapper binds w here and has_bias is 0.
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

// Invocations per workgroup and rows per invocation: 256 rows of out per workgroup.
const WG: u32 = 64u;
const ROWS: u32 = 4u;

// Finishes 4 columns of one row: bias, activation, zeroed padding columns, accumulate, store.
fn store4(row: u32, c4: u32, acc: vec4<f32>) {
    var v = acc;
    if (op_has_bias() != 0u) {
        v += bias[c4];
    }
    let cols = vec4<u32>(4u * c4) + vec4<u32>(0u, 1u, 2u, 3u);
    let at = row * op_n4() + c4;
    var prior = vec4<f32>(0.0);
    if (op_accumulate() != 0u) {
        prior = out[at];
    }
    out[at] = epilogue(v, prior, op_accumulate(), op_act(), p.slope, cols < vec4<u32>(op_n()));
}

@compute @workgroup_size(64)
fn linear(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_index) lid: u32) {
    let tiles = (op_n4() + 1u) / 2u;
    let group = wid.x + wid.y * nwg.x;
    let tile = group % tiles;
    let row0 = ((group / tiles) * WG + lid) * ROWS;
    if (row0 >= op_m()) {
        return;
    }
    // Rows past the end of x or w are clamped to the last one; their results are dropped or zeroed.
    let last_m = op_m() - 1u;
    let last_n = op_n() - 1u;
    let x0 = row0 * op_k4();
    let x1 = min(row0 + 1u, last_m) * op_k4();
    let x2 = min(row0 + 2u, last_m) * op_k4();
    let x3 = min(row0 + 3u, last_m) * op_k4();
    let col0 = 8u * tile;
    let w0 = min(col0, last_n) * op_w_ld4();
    let w1 = min(col0 + 1u, last_n) * op_w_ld4();
    let w2 = min(col0 + 2u, last_n) * op_w_ld4();
    let w3 = min(col0 + 3u, last_n) * op_w_ld4();
    let w4 = min(col0 + 4u, last_n) * op_w_ld4();
    let w5 = min(col0 + 5u, last_n) * op_w_ld4();
    let w6 = min(col0 + 6u, last_n) * op_w_ld4();
    let w7 = min(col0 + 7u, last_n) * op_w_ld4();
    // acc<row><half>: columns 0..3 (half 0) and 4..7 (half 1) of the block.
    var acc00 = vec4<f32>(0.0);
    var acc01 = vec4<f32>(0.0);
    var acc10 = vec4<f32>(0.0);
    var acc11 = vec4<f32>(0.0);
    var acc20 = vec4<f32>(0.0);
    var acc21 = vec4<f32>(0.0);
    var acc30 = vec4<f32>(0.0);
    var acc31 = vec4<f32>(0.0);
    for (var k = 0u; k < op_k4(); k++) {
        let b0 = vec4<f32>(w[w0 + k]);
        let b1 = vec4<f32>(w[w1 + k]);
        let b2 = vec4<f32>(w[w2 + k]);
        let b3 = vec4<f32>(w[w3 + k]);
        let b4 = vec4<f32>(w[w4 + k]);
        let b5 = vec4<f32>(w[w5 + k]);
        let b6 = vec4<f32>(w[w6 + k]);
        let b7 = vec4<f32>(w[w7 + k]);
        let a0 = x[x0 + k];
        let a1 = x[x1 + k];
        let a2 = x[x2 + k];
        let a3 = x[x3 + k];
        acc00 += vec4<f32>(dot(a0, b0), dot(a0, b1), dot(a0, b2), dot(a0, b3));
        acc01 += vec4<f32>(dot(a0, b4), dot(a0, b5), dot(a0, b6), dot(a0, b7));
        acc10 += vec4<f32>(dot(a1, b0), dot(a1, b1), dot(a1, b2), dot(a1, b3));
        acc11 += vec4<f32>(dot(a1, b4), dot(a1, b5), dot(a1, b6), dot(a1, b7));
        acc20 += vec4<f32>(dot(a2, b0), dot(a2, b1), dot(a2, b2), dot(a2, b3));
        acc21 += vec4<f32>(dot(a2, b4), dot(a2, b5), dot(a2, b6), dot(a2, b7));
        acc30 += vec4<f32>(dot(a3, b0), dot(a3, b1), dot(a3, b2), dot(a3, b3));
        acc31 += vec4<f32>(dot(a3, b4), dot(a3, b5), dot(a3, b6), dot(a3, b7));
    }
    // One loop over the block's 8 vec4s rather than 8 inlined copies of the epilogue (GELU is long).
    let block = array<vec4<f32>, 8>(acc00, acc01, acc10, acc11, acc20, acc21, acc30, acc31);
    for (var i = 0u; i < 8u; i++) {
        let row = row0 + i / 2u;
        let c4 = 2u * tile + i % 2u;
        // The second half of the last tile may lie past ld(N).
        if (row < op_m() && c4 < op_n4()) {
            store4(row, c4, block[i]);
        }
    }
}

// `linear_tiled`: the classic GPU tiling (tiles.wgsl). A workgroup of 16 x 16 invocations computes a TILE x TILE
// tile of out; per step along K each invocation loads one vec4 of a row of x and one of a row of w (neighbouring
// invocations read contiguous bytes), stages them in workgroup memory, and multiplies the staged step into its
// block, so each value loaded from memory serves TILE outputs. The next step's vec4s are loaded into registers
// while the staged one is multiplied (double buffering through registers, as workgroup memory holds one step).
//
// Split K: where out has too few tiles to fill a GPU (M = 300 rows: 3 x 12 tiles on a 1536-column layer), K is
// cut into `splits` ranges, a workgroup per (tile, range); each writes its raw sums to the partials (bound as
// `out`, [splits * m, n4] vec4s) and `linear_reduce` adds the ranges up and finishes (bias, activation,
// accumulation) into out.
//
// Layer norm in the prologue (`norm` = 1): x's rows are normalised as they are staged, out = act(LN(x) · wᵀ +
// bias) with LN's gamma and beta bound at 5 and 6, so the normalised rows are never written (the pre-norm of
// every transformer layer). The rows' statistics come from layernorm.wgsl's `row_stats`, run before (binding 7,
// a vec4 per row: the deviations' reference x0, their mean delta and 1 / std), rather than being summed here by
// every workgroup that stages the row: in the GEMM lab on an H200 that prologue made 300x1536x1536 3.4x slower
// and 4800x768x2304 1.4x.
@group(0) @binding(5) var<storage, read> gamma: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> beta: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> stats: array<vec4<f32>>;

// What normalises one row as it is staged: its first element, the mean of the deviations from it, 1 / std.
struct RowNorm {
    x0: f32,
    delta: f32,
    rstd: f32,
}

// Row `row`'s statistics when `norm` is 1, else the identity.
fn row_norm(row: u32) -> RowNorm {
    if (op_norm() == 0u) {
        return RowNorm(0.0, 0.0, 1.0);
    }
    let s = stats[row];
    return RowNorm(s.x, s.y, s.z);
}

// Vec4 k of a row of x as staged: normalised when `norm` is 1 (zero in the padding columns, where gamma and
// beta are zero).
fn x_staged(at: u32, k: u32, n: RowNorm) -> vec4<f32> {
    let v = x[at + k];
    if (op_norm() == 0u) {
        return v;
    }
    return ((v - n.x0) - n.delta) * n.rstd * gamma[k] + beta[k];
}

// The step at vec4 k of x's row at xa (normalised as `norm` says) and w's row at wa; zeros past k_end.
fn load_step(k: u32, k_end: u32, xa: u32, wa: u32, norm: RowNorm) -> Staged {
    if (k >= k_end) {
        return Staged();
    }
    return Staged(vec4<TileFloat>(x_staged(xa, k, norm)), vec4<TileFloat>(w[wa + k]));
}

// Stores vec4 `v` of the block at row `row`, vec4 column `c4` of out: finished (store4), or raw into split's
// range of the partials.
fn store_sum(row: u32, c4: u32, split: u32, v: vec4<f32>) {
    if (row >= op_m() || c4 >= op_n4()) {
        return;
    }
    if (op_splits() == 1u) {
        store4(row, c4, v);
    } else {
        out[(split * op_m() + row) * op_n4() + c4] = v;
    }
}

@compute @workgroup_size(16, 16)
fn linear_tiled(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tiles = (op_n4() + TILE / 4u - 1u) / (TILE / 4u);
    let group = wid.x + wid.y * nwg.x;
    let tile = group % tiles;
    let rest = group / tiles;
    let row0 = (rest % op_m_tiles()) * TILE;
    let split = rest / op_m_tiles();
    // The same for every invocation of the workgroup, so the barriers below stay in uniform control flow.
    if (split >= op_splits()) {
        return;
    }
    let k_begin = split * op_k_split4();
    let k_end = min(op_k4(), k_begin + op_k_split4());
    let kk = li % TILE_K4;
    // Rows past the end of x or w are clamped to the last one (their results are dropped or zeroed).
    let xa = min(row0 + li / TILE_K4, op_m() - 1u) * op_k4();
    let wa = min(tile * TILE + li / TILE_K4, op_n() - 1u) * op_w_ld4();
    let norm = row_norm(min(row0 + li / TILE_K4, op_m() - 1u));
    var next = load_step(k_begin + kk, k_end, xa, wa, norm);
    // This invocation's block of out (tiles.wgsl), in registers: named variables (gen_tiles.py says why).
    // BEGIN sums: written by tools/codegen/gen_tiles.py
    var sums_0 = vec4<f32>(0.0);
    var sums_1 = vec4<f32>(0.0);
    var sums_2 = vec4<f32>(0.0);
    var sums_3 = vec4<f32>(0.0);
    var sums_4 = vec4<f32>(0.0);
    var sums_5 = vec4<f32>(0.0);
    var sums_6 = vec4<f32>(0.0);
    var sums_7 = vec4<f32>(0.0);
    var sums_8 = vec4<f32>(0.0);
    var sums_9 = vec4<f32>(0.0);
    var sums_10 = vec4<f32>(0.0);
    var sums_11 = vec4<f32>(0.0);
    var sums_12 = vec4<f32>(0.0);
    var sums_13 = vec4<f32>(0.0);
    var sums_14 = vec4<f32>(0.0);
    var sums_15 = vec4<f32>(0.0);
    // END sums
    for (var k0 = k_begin; k0 < k_end; k0 += TILE_K4) {
        stage_step(li, next);
        workgroupBarrier();
        next = load_step(k0 + TILE_K4 + kk, k_end, xa, wa, norm);
        // BEGIN multiply_staged: written by tools/codegen/gen_tiles.py
        {
            let a0 = x_tile[0u + lid.y];
            let a1 = x_tile[16u + lid.y];
            let b0 = vec4<f32>(w_tile[0u + lid.x]);
            let b1 = vec4<f32>(w_tile[16u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[32u + lid.y];
            let a1 = x_tile[48u + lid.y];
            let b0 = vec4<f32>(w_tile[32u + lid.x]);
            let b1 = vec4<f32>(w_tile[48u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[64u + lid.y];
            let a1 = x_tile[80u + lid.y];
            let b0 = vec4<f32>(w_tile[64u + lid.x]);
            let b1 = vec4<f32>(w_tile[80u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[96u + lid.y];
            let a1 = x_tile[112u + lid.y];
            let b0 = vec4<f32>(w_tile[96u + lid.x]);
            let b1 = vec4<f32>(w_tile[112u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[128u + lid.y];
            let a1 = x_tile[144u + lid.y];
            let b0 = vec4<f32>(w_tile[128u + lid.x]);
            let b1 = vec4<f32>(w_tile[144u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[160u + lid.y];
            let a1 = x_tile[176u + lid.y];
            let b0 = vec4<f32>(w_tile[160u + lid.x]);
            let b1 = vec4<f32>(w_tile[176u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[192u + lid.y];
            let a1 = x_tile[208u + lid.y];
            let b0 = vec4<f32>(w_tile[192u + lid.x]);
            let b1 = vec4<f32>(w_tile[208u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[224u + lid.y];
            let a1 = x_tile[240u + lid.y];
            let b0 = vec4<f32>(w_tile[224u + lid.x]);
            let b1 = vec4<f32>(w_tile[240u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        // END multiply_staged
        workgroupBarrier();
    }
    let first_row = row0;
    let first_c4 = tile * (TILE / 4u);
    // BEGIN stores: written by tools/codegen/gen_tiles.py
    store_sum(first_row + block_row(lid.y, 0u), first_c4 + block_col4(lid.x, 0u), split, sums_0);
    store_sum(first_row + block_row(lid.y, 0u), first_c4 + block_col4(lid.x, 1u), split, sums_1);
    store_sum(first_row + block_row(lid.y, 1u), first_c4 + block_col4(lid.x, 0u), split, sums_2);
    store_sum(first_row + block_row(lid.y, 1u), first_c4 + block_col4(lid.x, 1u), split, sums_3);
    store_sum(first_row + block_row(lid.y, 2u), first_c4 + block_col4(lid.x, 0u), split, sums_4);
    store_sum(first_row + block_row(lid.y, 2u), first_c4 + block_col4(lid.x, 1u), split, sums_5);
    store_sum(first_row + block_row(lid.y, 3u), first_c4 + block_col4(lid.x, 0u), split, sums_6);
    store_sum(first_row + block_row(lid.y, 3u), first_c4 + block_col4(lid.x, 1u), split, sums_7);
    store_sum(first_row + block_row(lid.y, 4u), first_c4 + block_col4(lid.x, 0u), split, sums_8);
    store_sum(first_row + block_row(lid.y, 4u), first_c4 + block_col4(lid.x, 1u), split, sums_9);
    store_sum(first_row + block_row(lid.y, 5u), first_c4 + block_col4(lid.x, 0u), split, sums_10);
    store_sum(first_row + block_row(lid.y, 5u), first_c4 + block_col4(lid.x, 1u), split, sums_11);
    store_sum(first_row + block_row(lid.y, 6u), first_c4 + block_col4(lid.x, 0u), split, sums_12);
    store_sum(first_row + block_row(lid.y, 6u), first_c4 + block_col4(lid.x, 1u), split, sums_13);
    store_sum(first_row + block_row(lid.y, 7u), first_c4 + block_col4(lid.x, 0u), split, sums_14);
    store_sum(first_row + block_row(lid.y, 7u), first_c4 + block_col4(lid.x, 1u), split, sums_15);
    // END stores
}

// `linear_reduce`: the ranges of a split `linear_tiled` added up and finished into out, an invocation per vec4
// of out. Bindings as for the other entry points, the partials in place of x (w is not read).
@compute @workgroup_size(64)
fn linear_reduce(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    _ = w[0];
    let index = (wid.x + wid.y * nwg.x) * WG + lid;
    if (index >= op_m() * op_n4()) {
        return;
    }
    let row = index / op_n4();
    let c4 = index % op_n4();
    var sum = vec4<f32>(0.0);
    for (var s = 0u; s < op_splits(); s++) {
        sum += x[(s * op_m() + row) * op_n4() + c4];
    }
    store4(row, c4, sum);
}
