// The workgroup-memory tiles of the GPU GEMMs (`MatmulKernel::Tiled`): matmul.wgsl's `linear_tiled` and
// conv.wgsl's `conv_tiled`, which this prelude is prepended to (matmul.wgsl says why these sizes and layouts).
// A workgroup of 16 x 16 invocations computes a TILE x TILE block of out: invocation (tx, ty) rows ty + 16 i
// (i < TILE_ROWS) by vec4 columns tx + 16 j (j < TILE_COLS4). Per step of TILE_K4 vec4s along K it stages TILE
// rows of x (or of the gathered input pixels) and TILE rows of w here, K-major; invocation li stages rows
// li / TILE_K4 and li / TILE_K4 + STAGE_STEP of both, at vec4 li % TILE_K4 of the step.
//
// 64 x 64 tiles with 32 floats of K a step (4 x 4 outputs per invocation) take 512 vec4s (16 KiB, WebGPU's
// guaranteed minimum) of workgroup memory. (128 x 128 tiles, 8 x 8 outputs an invocation, ran at half the speed
// on an H200.)
//
// The tiles hold f32, or f16 in the f16-activation variants (`matmul_f16_act`, `Precision::F16Activations`),
// which replace TileFloat and `linear_tiled`'s call of multiply_staged: there x and w are rounded to f16 as they
// are staged, each step's products are summed in f16 (32 terms, at twice f32's rate on GPUs with packed f16),
// and the steps' sums in f32.

const TILE: u32 = 64u;
// vec4s of K per step.
const TILE_K4: u32 = 8u;
const TILE_ROWS: u32 = TILE / 16u;
const TILE_COLS4: u32 = TILE / 64u;
const STAGE_STEP: u32 = 256u / TILE_K4;
// vec4s of out per invocation: acc[i * TILE_COLS4 + j] is row ty + 16 i, vec4 column tx + 16 j.
const BLOCK: u32 = TILE_ROWS * TILE_COLS4;
alias TileFloat = f32;
var<workgroup> x_tile: array<vec4<TileFloat>, 512>;
var<workgroup> w_tile: array<vec4<TileFloat>, 512>;

// Stages vec4 kk of row r of x's tile and of w's. w's rows are permuted: row c (a column of out, in vec4 column
// c4 = c / 4, lane c % 4) sits at (4 (c4 / 16) + c % 4) * 16 + c4 % 16, so that the 16 invocations of a row of the
// workgroup (tx = c4 % 16) read 16 consecutive vec4s.
fn stage(kk: u32, r: u32, xv: vec4<TileFloat>, wv: vec4<TileFloat>) {
    x_tile[kk * TILE + r] = xv;
    let c4 = r / 4u;
    w_tile[kk * TILE + (4u * (c4 / 16u) + r % 4u) * 16u + c4 % 16u] = wv;
}

// One step's vec4s an invocation stages, loaded a step ahead: rows r and r + STAGE_STEP of x's tile (x0, x1)
// and of w's (w0, w1); `Staged()` (zeros) past the end of K.
struct Staged {
    x0: vec4<TileFloat>,
    x1: vec4<TileFloat>,
    w0: vec4<TileFloat>,
    w1: vec4<TileFloat>,
}

// Stages an invocation's step at vec4 kk of its rows r and r + STAGE_STEP.
fn stage_step(kk: u32, r: u32, s: Staged) {
    stage(kk, r, s.x0, s.w0);
    stage(kk, r + STAGE_STEP, s.x1, s.w1);
}

// One staged step's products added to invocation (tx, ty)'s `sums`, in the tiles' precision (f32 tiles: the
// block itself).
fn multiply_staged(tx: u32, ty: u32, sums: ptr<function, array<vec4<TileFloat>, BLOCK>>) {
    for (var kk = 0u; kk < TILE_K4; kk++) {
        let at = kk * TILE;
        // b[4 j + l]: the weights of column l of this invocation's vec4 column j.
        var b: array<vec4<TileFloat>, 4u * TILE_COLS4>;
        for (var j = 0u; j < 4u * TILE_COLS4; j++) {
            b[j] = w_tile[at + j * 16u + tx];
        }
        for (var i = 0u; i < TILE_ROWS; i++) {
            let a = x_tile[at + ty + 16u * i];
            for (var j = 0u; j < TILE_COLS4; j++) {
                (*sums)[i * TILE_COLS4 + j] += vec4<TileFloat>(
                    dot(a, b[4u * j]), dot(a, b[4u * j + 1u]), dot(a, b[4u * j + 2u]), dot(a, b[4u * j + 3u]));
            }
        }
    }
}
