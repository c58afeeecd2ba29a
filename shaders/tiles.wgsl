// The workgroup-memory tiles of the GPU GEMMs (`MatmulKernel::Tiled`): matmul.wgsl's `linear_tiled` and
// conv.wgsl's `conv_tiled`, which this prelude is prepended to (matmul.wgsl says why these sizes and layouts).
// A workgroup of 16 x 16 invocations computes a TILE x TILE block of out; per step of TILE_K4 vec4s along K it
// stages TILE rows of x (or of the gathered input pixels) and TILE rows of w here, K-major, and invocation
// (tx, ty) takes rows ty + 16 i (i < 4) by the 4 columns of vec4 column tx from them.

const TILE: u32 = 64u;
// vec4s of K per step.
const TILE_K4: u32 = 8u;
var<workgroup> x_tile: array<vec4<f32>, 512>;
var<workgroup> w_tile: array<vec4<f32>, 512>;

// Stages vec4 kk of row r of x's tile and of w's. w's rows are permuted, row c at (c % 4) * 16 + c / 4, so that
// invocation tx's column j sits at j * 16 + tx and the 16 invocations of a row read 16 consecutive vec4s.
fn stage(kk: u32, r: u32, xv: vec4<f32>, wv: vec4<f32>) {
    x_tile[kk * TILE + r] = xv;
    w_tile[kk * TILE + (r % 4u) * 16u + r / 4u] = wv;
}

// One staged step's products added to invocation (tx, ty)'s block (acc[i]: row ty + 16 i).
fn multiply_staged(tx: u32, ty: u32, acc: ptr<function, array<vec4<f32>, 4>>) {
    for (var kk = 0u; kk < TILE_K4; kk++) {
        let at = kk * TILE;
        let b0 = w_tile[at + tx];
        let b1 = w_tile[at + 16u + tx];
        let b2 = w_tile[at + 32u + tx];
        let b3 = w_tile[at + 48u + tx];
        let a0 = x_tile[at + ty];
        let a1 = x_tile[at + 16u + ty];
        let a2 = x_tile[at + 32u + ty];
        let a3 = x_tile[at + 48u + ty];
        (*acc)[0] += vec4<f32>(dot(a0, b0), dot(a0, b1), dot(a0, b2), dot(a0, b3));
        (*acc)[1] += vec4<f32>(dot(a1, b0), dot(a1, b1), dot(a1, b2), dot(a1, b3));
        (*acc)[2] += vec4<f32>(dot(a2, b0), dot(a2, b1), dot(a2, b2), dot(a2, b3));
        (*acc)[3] += vec4<f32>(dot(a3, b0), dot(a3, b1), dot(a3, b2), dot(a3, b3));
    }
}
