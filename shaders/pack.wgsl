// Packs a [rows, cols] matrix into a texture in the layout of texels.wgsl (row or 8-lane), zero-filling the
// padding texels and the rows past the matrix's (up to a whole tile of 32 rows in the 8-lane layout, and any
// zero rows asked for): what matmul_lanes reads. A row may be cut into segments (a convolution weight's taps, attention's
// heads), each padded to whole blocks of 8 texels. The matrix is columns col.. of the source's rows, or the
// transpose of those (attention's values, which matmul_lanes reads as w).
// - pack: a workgroup per 8 packed rows;
// - pack_softmax_rows: softmax(scale · row) of each row into the row layout, one invocation per row
//   (attention's weights, from its scores).

struct Params {
    // Rows of the packed matrix.
    rows: u32,
    // vec4s per row of the source buffer: ld / 4.
    ld4: u32,
    // Texels per packed row: segments of seg4p texels.
    k4p: u32,
    // 1 (row layout) or 8 (8-lane layout).
    lanes: u32,
    // Texels to write.
    texels: u32,
    // vec4s of the matrix per segment, and packed texels per segment (seg4 rounded up to 8).
    seg4: u32,
    seg4p: u32,
    // The matrix's first column in the source (a multiple of 4 unless transposed).
    col: u32,
    // 1: the matrix is the transpose of the source's columns col.. (its row r is source column col + r).
    transposed: u32,
    // Columns of the matrix (those of the last vec4 past it read as zero when transposed or in softmax).
    cols: u32,
    // pack_softmax_rows: the logits are scale · source.
    scale: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var dst: texture_storage_2d<rgba32float, write>;

// Element (r, c) of the source.
fn source(r: u32, c: u32) -> f32 {
    return src[r * p.ld4 + c / 4u][c % 4u];
}

// One workgroup per 8 packed rows, walking them 8 texels at a time (a block: seg4p is a multiple of 8, so a
// block lies in one segment). Everything but the lane's row and step is uniform, which llvmpipe computes once
// for all lanes (a division that differs between lanes costs a scalar division per lane), and few large
// workgroups beat many small ones there (the official RP-SRT k=8 render's packing: 19 ms with a workgroup per
// 8 rows x 8 texels, 15.6 ms with this; docs/PERFORMANCE.md).
@compute @workgroup_size(64)
fn pack(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let row_group = wid.x + wid.y * nwg.x;
    let lane = lid % 8u;
    let packed_row = row_group * 8u + lane;
    var row = packed_row;
    var first = packed_row * p.k4p + lid / 8u;
    var step = 1u;
    if (p.lanes == 8u) {
        row = tile_row(packed_row);
        first = row_group * p.k4p * 8u + lid;
        step = 8u;
    }
    if (first >= p.texels) {
        return;
    }
    for (var block = 0u; block < p.k4p / 8u; block++) {
        let c4 = block * 8u + lid / 8u;
        let segment = block * 8u / p.seg4p;
        let in_segment = c4 - segment * p.seg4p;
        var v = vec4<f32>(0.0);
        if (row < p.rows && in_segment < p.seg4) {
            let at = segment * p.seg4 + in_segment;
            if (p.transposed == 0u) {
                v = src[row * p.ld4 + p.col / 4u + at];
            } else {
                for (var i = 0u; i < 4u; i++) {
                    if (4u * at + i < p.cols) {
                        v[i] = source(4u * at + i, p.col + row);
                    }
                }
            }
        }
        textureStore(dst, texel(first + block * 8u * step), v);
    }
}

// Row r's logits at vec4 c4 (columns past cols: -inf stands in, weight 0).
fn logits(r: u32, c4: u32) -> vec4<f32> {
    let real = vec4<u32>(4u * c4) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(p.cols);
    return select(vec4<f32>(-3.0e38), src[r * p.ld4 + p.col / 4u + c4] * p.scale, real);
}

// Softmax as PyTorch computes it: the scaled logits rounded to f32, max subtracted, exp, divided by the sum.
@compute @workgroup_size(64)
fn pack_softmax_rows(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                     @builtin(local_invocation_index) lid: u32) {
    let r = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (r >= p.rows) {
        return;
    }
    let vec4s = (p.cols + 3u) / 4u;
    var m4 = vec4<f32>(-3.0e38);
    for (var c4 = 0u; c4 < vec4s; c4++) {
        m4 = max(m4, logits(r, c4));
    }
    let m = max(max(m4.x, m4.y), max(m4.z, m4.w));
    var sum4 = vec4<f32>(0.0);
    for (var c4 = 0u; c4 < vec4s; c4++) {
        sum4 += exp(logits(r, c4) - m);
    }
    let sum = (sum4.x + sum4.y) + (sum4.z + sum4.w);
    for (var c4 = 0u; c4 < p.k4p; c4++) {
        var v = vec4<f32>(0.0);
        if (c4 < vec4s) {
            v = exp(logits(r, c4) - m) / sum;
        }
        textureStore(dst, texel(r * p.k4p + c4), v);
    }
}
