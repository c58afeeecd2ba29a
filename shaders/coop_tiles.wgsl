// The tensor kernels' GEMM (`MatmulKernel::Coop`): f16 cooperative matrices (tensor cores) with f32 accumulators,
// staged through workgroup memory. This prelude comes after coop_size.wgsl (the tile size CT and the matrix
// aliases) and before the file whose entry point calls `coop_gemm`: matmul_coop.wgsl (linear layers: x · wᵀ) and conv_coop.wgsl
// (convolutions as an implicit GEMM). The includer defines the GEMM's operands and its epilogue:
//   coop_m(), coop_n(), coop_k4(): out is M x N, a sum over K (in vec4s);
//   coop_splits(), coop_k_split4(): K cut into ranges of k_split4 vec4s (a multiple of COOP_BK / 4), one per
//     workgroup, when the output's tiles are too few to fill a GPU; store_sum writes each range's raw sums;
//   coop_a4(row, k4), coop_b4(col, k4): vec4 k4 of A's row and of Bᵀ's row (w's row: a column of out), in f32;
//     called only in range (row < M, col < N, k4 < K4);
//   store_sum(row, c4, split, v): finishes (bias, activation, residual, zeroed padding) or stores the raw sums of
//     vec4 column c4 of out's row; checks both against out's size.
//
// Numbers: A and B are rounded to f16 as they are staged (values beyond f16's range become infinite), the
// products summed in f32, the epilogue in f32 (`Precision::F16Activations`).
//
// Tiling. The adapter's tile is CT x CT x CT (coop_size.wgsl: 16 on NVIDIA and AMD; 8 on Apple and Mesa's
// lavapipe). A workgroup is COOP_SG_M x COOP_SG_N subgroups of
// COOP_LANES lanes (the adapter's subgroup width, read at run time: device::CoopShape) and computes a
// COOP_BM x COOP_BN tile of out; each subgroup a 2CT x 2CT block of it in 2 x 2 accumulators, its A fragments
// reused across its columns and its B fragments across its rows. The tile's shape is override constants, so a
// tuner tries shapes without new code (device::CoopShape, tools/bench/gpu_bench.sh).
//
// Staging. Per step of COOP_BK floats of K, the workgroup stages COOP_BM rows of A and COOP_BN rows of Bᵀ in
// workgroup memory as f16, K-contiguous (A row-major, B column-major), each row padded by 8 halves (16 bytes: a
// stride that stays 16-byte aligned and spreads rows over the banks). Two such stages alternate: the step after
// the current one is loaded (vec4 loads from global memory) and stored while the current one is multiplied, so
// one barrier a step keeps them apart. Rows past M or N and K past the range are staged as zeros, so every
// fragment load reads staged memory, in range by construction.
//
// Epilogue. Each subgroup stores its accumulators one at a time into its own CT x CT f32 tile of workgroup
// memory, and its lanes finish whole vec4s of out from there with store_sum (bounds-checked).

// The workgroup's shape (kernels::coop_constants, from device::CoopShape).
override COOP_LANES: u32 = 32u;
override COOP_SG_M: u32 = 2u;
override COOP_SG_N: u32 = 2u;
override COOP_BK: u32 = 32u;
override COOP_WG: u32 = COOP_SG_M * COOP_SG_N * COOP_LANES;
override COOP_BM: u32 = COOP_SG_M * 2u * CT;
override COOP_BN: u32 = COOP_SG_N * 2u * CT;
// Halves per staged row, and per stage of A and of B.
override COOP_LD: u32 = COOP_BK + 8u;
override COOP_A_STAGE: u32 = COOP_BM * COOP_LD;
override COOP_B_STAGE: u32 = COOP_BN * COOP_LD;
override COOP_A_HALVES: u32 = 2u * COOP_A_STAGE;
override COOP_B_HALVES: u32 = 2u * COOP_B_STAGE;
override COOP_C_FLOATS: u32 = COOP_SG_M * COOP_SG_N * CT * CT;

var<workgroup> coop_a_tile: array<f16, COOP_A_HALVES>;
var<workgroup> coop_b_tile: array<f16, COOP_B_HALVES>;
var<workgroup> coop_c_tile: array<f32, COOP_C_FLOATS>;
// The workgroup's group index, read back with workgroupUniformLoad: naga's uniformity analysis takes a function's
// arguments as non-uniform, and cooperative operations must be in uniform control flow.
var<workgroup> coop_group: u32;

// A workgroup's tile of out: its first row and column, its K range (vec4s), and whether it has one (the grid may
// have more groups). The same for the whole workgroup, so the barriers and cooperative operations stay in uniform
// control flow.
struct CoopTile {
    row0: u32,
    col0: u32,
    split: u32,
    k_begin: u32,
    k_end: u32,
    steps: u32,
    valid: bool,
}

// The workgroup's tile (its group index from `coop_group`, which coop_gemm set): column tiles fastest, then row
// tiles, then K ranges. No arguments, so that naga sees its result as uniform.
fn coop_tile() -> CoopTile {
    let group = workgroupUniformLoad(&coop_group);
    let col_tiles = (coop_n() + COOP_BN - 1u) / COOP_BN;
    let row_tiles = (coop_m() + COOP_BM - 1u) / COOP_BM;
    let rest = group / col_tiles;
    let split = rest / row_tiles;
    let k_begin = split * coop_k_split4();
    let k_end = min(coop_k4(), k_begin + coop_k_split4());
    let bk4 = COOP_BK / 4u;
    let steps = select(0u, (k_end - k_begin + bk4 - 1u) / bk4, k_end > k_begin);
    return CoopTile((rest % row_tiles) * COOP_BM, (group % col_tiles) * COOP_BN, split, k_begin, k_end, steps,
                    split < coop_splits());
}

// Stores the f16 of a vec4 at half `at` of A's (`a_side`) or B's stages.
fn coop_put(a_side: bool, at: u32, v: vec4<f16>) {
    if (a_side) {
        coop_a_tile[at] = v.x;
        coop_a_tile[at + 1u] = v.y;
        coop_a_tile[at + 2u] = v.z;
        coop_a_tile[at + 3u] = v.w;
    } else {
        coop_b_tile[at] = v.x;
        coop_b_tile[at + 1u] = v.y;
        coop_b_tile[at + 2u] = v.z;
        coop_b_tile[at + 3u] = v.w;
    }
}

// Stages step `step` of the tile into stage step % 2: invocation li takes vec4s li, li + COOP_WG, .. of A's and
// of B's, row i / (COOP_BK / 4), vec4 i % (COOP_BK / 4) of the step; zeros past M, N and the K range.
fn coop_stage(t: CoopTile, step: u32, li: u32) {
    let bk4 = COOP_BK / 4u;
    let k0 = t.k_begin + step * bk4;
    let stage = step % 2u;
    for (var i = li; i < COOP_BM * bk4; i += COOP_WG) {
        let r = i / bk4;
        let k4 = k0 + i % bk4;
        var v = vec4<f32>(0.0);
        if (t.row0 + r < coop_m() && k4 < t.k_end) {
            v = coop_a4(t.row0 + r, k4);
        }
        coop_put(true, stage * COOP_A_STAGE + r * COOP_LD + 4u * (i % bk4), vec4<f16>(v));
    }
    for (var i = li; i < COOP_BN * bk4; i += COOP_WG) {
        let c = i / bk4;
        let k4 = k0 + i % bk4;
        var v = vec4<f32>(0.0);
        if (t.col0 + c < coop_n() && k4 < t.k_end) {
            v = coop_b4(t.col0 + c, k4);
        }
        coop_put(false, stage * COOP_B_STAGE + c * COOP_LD + 4u * (i % bk4), vec4<f16>(v));
    }
}

// Finishes the CT x CT block at (r0, c0) of the tile from the subgroup's staged sums at `at`: lane `lane` takes
// vec4s lane, lane + COOP_LANES, .. of it.
fn coop_emit(t: CoopTile, r0: u32, c0: u32, at: u32, lane: u32) {
    for (var i = lane; i < CT * CT / 4u; i += COOP_LANES) {
        let r = i / (CT / 4u);
        let c4 = i % (CT / 4u);
        let s = at + 4u * i;
        let v = vec4<f32>(coop_c_tile[s], coop_c_tile[s + 1u], coop_c_tile[s + 2u], coop_c_tile[s + 3u]);
        store_sum(t.row0 + r0 + r, (t.col0 + c0) / 4u + c4, t.split, v);
    }
}

// The GEMM of group `group`, called by every invocation of the workgroup (li: local index; sg_id: subgroup id;
// lane: index within the subgroup).
fn coop_gemm(group: u32, li: u32, sg_id: u32, lane: u32) {
    if (li == 0u) {
        coop_group = group;
    }
    let t = coop_tile();
    if (!t.valid) {
        return;
    }
    // Subgroups past the tile's (only where the driver made subgroups narrower than COOP_LANES, which
    // device::CoopShape rules out) repeat the last block rather than read past the stages.
    let sg = min(sg_id, COOP_SG_M * COOP_SG_N - 1u);
    let sr = (sg / COOP_SG_N) * 2u * CT;
    let sc = (sg % COOP_SG_N) * 2u * CT;
    var acc00 = CoopC();
    var acc01 = CoopC();
    var acc10 = CoopC();
    var acc11 = CoopC();
    if (t.steps > 0u) {
        coop_stage(t, 0u, li);
    }
    workgroupBarrier();
    for (var step = 0u; step < t.steps; step++) {
        if (step + 1u < t.steps) {
            coop_stage(t, step + 1u, li);
        }
        let a_base = (step % 2u) * COOP_A_STAGE;
        let b_base = (step % 2u) * COOP_B_STAGE;
        for (var kk = 0u; kk < COOP_BK; kk += CT) {
            // naga's SPIR-V writer needs each cooperative load's index bound by `let` first (its issue 7315).
            let a0_at = a_base + sr * COOP_LD + kk;
            let a1_at = a_base + (sr + CT) * COOP_LD + kk;
            let b0_at = b_base + sc * COOP_LD + kk;
            let b1_at = b_base + (sc + CT) * COOP_LD + kk;
            let a0 = coopLoadT<CoopA>(&coop_a_tile[a0_at], COOP_LD);
            let a1 = coopLoadT<CoopA>(&coop_a_tile[a1_at], COOP_LD);
            let b0 = coopLoad<CoopB>(&coop_b_tile[b0_at], COOP_LD);
            let b1 = coopLoad<CoopB>(&coop_b_tile[b1_at], COOP_LD);
            acc00 = coopMultiplyAdd(a0, b0, acc00);
            acc01 = coopMultiplyAdd(a0, b1, acc01);
            acc10 = coopMultiplyAdd(a1, b0, acc10);
            acc11 = coopMultiplyAdd(a1, b1, acc11);
        }
        workgroupBarrier();
    }
    let at = sg * CT * CT;
    coopStoreT(acc00, &coop_c_tile[at], CT);
    workgroupBarrier();
    coop_emit(t, sr, sc, at, lane);
    workgroupBarrier();
    coopStoreT(acc01, &coop_c_tile[at], CT);
    workgroupBarrier();
    coop_emit(t, sr, sc + CT, at, lane);
    workgroupBarrier();
    coopStoreT(acc10, &coop_c_tile[at], CT);
    workgroupBarrier();
    coop_emit(t, sr + CT, sc, at, lane);
    workgroupBarrier();
    coopStoreT(acc11, &coop_c_tile[at], CT);
    workgroupBarrier();
    coop_emit(t, sr + CT, sc + CT, at, lane);
}
