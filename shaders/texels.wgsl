// Matrices in rgba32float storage textures (prepended to pack and matmul_lanes by kernels/mod.rs).
//
// A packed [rows, cols] matrix is a sequence of texels of 4 consecutive columns, k4p = ceil(cols / 4)
// rounded up to 8 texels per row, zeros past the end of a row. In the row layout (lanes = 1) texel
// r * k4p + c4 holds columns 4·c4.. of row r; in the 8-lane layout (lanes = 8) packed rows go in groups of 8
// whose texels interleave, ((r / 8) · k4p + c4) · 8 + r % 8, so that 8 lanes reading the same step of 8
// packed rows read 8 consecutive texels, and each tile of 32 rows is transposed: packed row 8j + l of a tile
// is its row 4l + j, so that lane l's four groups j are four consecutive rows of w, columns of matmul_lanes'
// out (`tile_row`). The sequence fills the texture row by row, TEXTURE_WIDTH texels wide (kernels/pack.rs
// sizes the textures).

const TEXTURE_WIDTH: u32 = 4096u;

// The row of the matrix that packed row `packed` of the 8-lane layout holds.
fn tile_row(packed: u32) -> u32 {
    return (packed / 32u) * 32u + (packed % 8u) * 4u + (packed / 8u) % 4u;
}

// The texture coordinates of texel t of the sequence.
fn texel(t: u32) -> vec2<u32> {
    return vec2<u32>(t % TEXTURE_WIDTH, t / TEXTURE_WIDTH);
}
