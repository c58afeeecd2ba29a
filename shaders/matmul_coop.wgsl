enable f16;
enable wgpu_cooperative_matrix;

// `linear_coop` (MatmulKernel::Coop): matmul.wgsl's linear layer on f16 cooperative matrices (tensor cores). This
// file comes first in its shader (for the `enable` directives), then activation.wgsl, tiles.wgsl and matmul.wgsl,
// whose Params, bindings 0-4, `op_*` accessors and `store4` epilogue (bias, activation, zeroed padding, accumulate)
// it shares; WGSL's module-scope declarations may come in any order. The f16-weight variant replaces WeightVec as
// for `matmul_f16`.
//
// A workgroup of 128 invocations, 4 subgroups of 32 lanes (device::COOP_LANES), computes a COOP_TILE x COOP_TILE
// tile of out: subgroup s the 32 x 32 quarter at rows 32 (s / 2), columns 32 (s % 2), as 2 x 2 accumulators of
// 16 x 16 in f32. Per step of COOP_K floats of K every invocation stages a quarter of the tiles' vec4s, rounded to
// f16, row-major (x's rows, and w's rows = the columns of out), zeros past the end of x's rows, w's rows and K;
// each subgroup then loads its 16 x 16 operands from there and multiplies. At the end the accumulators go through
// workgroup memory so that each invocation finishes whole vec4s of out with `store4`. No K split and no layer
// norm in the prologue yet (kernels::matmul runs the norm before): a first, plain version to measure.
//
// naga 30's SPIR-V writer panics ("Expression [N] is not cached") when a coopLoad/coopStore pointer indexes with
// an inline expression, so every such index is a `let` first.

const COOP_TILE: u32 = 64u;
const COOP_K: u32 = 32u;
// vec4s of a staged row, and of a tile.
const COOP_ROW4: u32 = 8u;
const COOP_TILE4: u32 = 512u;
var<workgroup> coop_x: array<f16, 2048>;
var<workgroup> coop_w: array<f16, 2048>;
// The finished sums, row-major, COOP_TILE floats a row.
var<workgroup> coop_out: array<f32, 4096>;

// Stages the f16 of a vec4 at float `at` of a staged tile.
fn coop_stage(x_side: bool, at: u32, v: vec4<f16>) {
    if (x_side) {
        coop_x[at] = v.x;
        coop_x[at + 1u] = v.y;
        coop_x[at + 2u] = v.z;
        coop_x[at + 3u] = v.w;
    } else {
        coop_w[at] = v.x;
        coop_w[at + 1u] = v.y;
        coop_w[at + 2u] = v.z;
        coop_w[at + 3u] = v.w;
    }
}

@compute @workgroup_size(128)
fn linear_coop(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32, @builtin(subgroup_id) sg: u32) {
    let tiles = (op_n4() + COOP_TILE / 4u - 1u) / (COOP_TILE / 4u);
    let group = wid.x + wid.y * nwg.x;
    // The same for the whole workgroup, so the barriers and cooperative operations stay in uniform control flow.
    if (group >= tiles * op_m_tiles()) {
        return;
    }
    let row0 = (group / tiles) * COOP_TILE;
    let col0 = (group % tiles) * COOP_TILE;
    // This subgroup's quarter: its first row and column within the tile.
    let sr = 32u * (sg / 2u);
    let sc = 32u * (sg % 2u);
    var acc00 = coop_mat16x16<f32, C>();
    var acc01 = coop_mat16x16<f32, C>();
    var acc10 = coop_mat16x16<f32, C>();
    var acc11 = coop_mat16x16<f32, C>();
    for (var k0 = 0u; k0 < op_k4(); k0 += COOP_K / 4u) {
        // Invocation li stages vec4s li, li + 128, .. of each tile: row i / COOP_ROW4, vec4 i % COOP_ROW4.
        for (var i = li; i < COOP_TILE4; i += 128u) {
            let r = i / COOP_ROW4;
            let k4 = k0 + i % COOP_ROW4;
            let in_k = k4 < op_k4();
            var xv = vec4<f16>(0.0);
            if (row0 + r < op_m() && in_k) {
                xv = vec4<f16>(x[(row0 + r) * op_k4() + k4]);
            }
            var wv = vec4<f16>(0.0);
            if (col0 + r < op_n() && in_k) {
                wv = vec4<f16>(w[(col0 + r) * op_w_ld4() + k4]);
            }
            coop_stage(true, 4u * i, xv);
            coop_stage(false, 4u * i, wv);
        }
        workgroupBarrier();
        for (var kk = 0u; kk < COOP_K; kk += 16u) {
            // A: rows of x, row-major. B (K x N) = wᵀ: w's rows are B's columns, so column-major.
            let a0_at = sr * COOP_K + kk;
            let a1_at = (sr + 16u) * COOP_K + kk;
            let b0_at = sc * COOP_K + kk;
            let b1_at = (sc + 16u) * COOP_K + kk;
            let a0 = coopLoadT<coop_mat16x16<f16, A>>(&coop_x[a0_at], COOP_K);
            let a1 = coopLoadT<coop_mat16x16<f16, A>>(&coop_x[a1_at], COOP_K);
            let b0 = coopLoad<coop_mat16x16<f16, B>>(&coop_w[b0_at], COOP_K);
            let b1 = coopLoad<coop_mat16x16<f16, B>>(&coop_w[b1_at], COOP_K);
            acc00 = coopMultiplyAdd(a0, b0, acc00);
            acc01 = coopMultiplyAdd(a0, b1, acc01);
            acc10 = coopMultiplyAdd(a1, b0, acc10);
            acc11 = coopMultiplyAdd(a1, b1, acc11);
        }
        workgroupBarrier();
    }
    let c00_at = sr * COOP_TILE + sc;
    let c01_at = sr * COOP_TILE + sc + 16u;
    let c10_at = (sr + 16u) * COOP_TILE + sc;
    let c11_at = (sr + 16u) * COOP_TILE + sc + 16u;
    coopStoreT(acc00, &coop_out[c00_at], COOP_TILE);
    coopStoreT(acc01, &coop_out[c01_at], COOP_TILE);
    coopStoreT(acc10, &coop_out[c10_at], COOP_TILE);
    coopStoreT(acc11, &coop_out[c11_at], COOP_TILE);
    workgroupBarrier();
    // Each invocation finishes vec4s li, li + 128, .. of the tile: row i / 16, vec4 column i % 16.
    for (var i = li; i < COOP_TILE * COOP_TILE / 4u; i += 128u) {
        let r = i / (COOP_TILE / 4u);
        let c4 = col0 / 4u + i % (COOP_TILE / 4u);
        if (row0 + r < op_m() && c4 < op_n4()) {
            let at = 4u * i;
            store4(row0 + r, c4, vec4<f32>(coop_out[at], coop_out[at + 1u], coop_out[at + 2u], coop_out[at + 3u]));
        }
    }
}
