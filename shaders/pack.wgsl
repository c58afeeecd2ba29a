// Packs a [rows, cols] buffer into a texture in the layout of texels.wgsl (row or 8-lane), zero-filling the
// padding texels and the rows past the source's (up to a whole group of lanes, and any zero rows asked
// for): what matmul_lanes reads. A row may be cut into segments (a convolution weight's taps), each padded
// to whole blocks of 8 texels. One invocation per texel.

struct Params {
    rows: u32,
    // vec4s per row of the source buffer: ld(cols) / 4.
    ld4: u32,
    // Texels per packed row: segments of seg4p texels.
    k4p: u32,
    // 1 (row layout) or 8 (8-lane layout).
    lanes: u32,
    // Texels to write.
    texels: u32,
    // Source vec4s per segment, and packed texels per segment (seg4 rounded up to 8).
    seg4: u32,
    seg4p: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var dst: texture_storage_2d<rgba32float, write>;

@compute @workgroup_size(64)
fn pack(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let t = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (t >= p.texels) {
        return;
    }
    let step = t / p.lanes;
    var row = (step / p.k4p) * p.lanes + t % p.lanes;
    if (p.lanes == 8u) {
        row = tile_row(row);
    }
    let c4 = step % p.k4p;
    let segment = c4 / p.seg4p;
    let in_segment = c4 % p.seg4p;
    var v = vec4<f32>(0.0);
    if (row < p.rows && in_segment < p.seg4) {
        v = src[row * p.ld4 + segment * p.seg4 + in_segment];
    }
    textureStore(dst, texel(t), v);
}
