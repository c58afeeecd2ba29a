// Packs a [rows, cols] buffer into a texture in the layout of texels.wgsl (row or 8-lane), zero-filling the
// padding texels and the rows up to a whole group of lanes: what matmul_lanes reads. One invocation per texel.

struct Params {
    rows: u32,
    // vec4s per row of the source buffer: ld(cols) / 4.
    ld4: u32,
    // Texels per packed row: ceil(cols / 4) rounded up to 8.
    k4p: u32,
    // 1 (row layout) or 8 (8-lane layout).
    lanes: u32,
    // Texels to write: rows rounded up to lanes, times k4p.
    texels: u32,
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
    let row = (step / p.k4p) * p.lanes + t % p.lanes;
    let c4 = step % p.k4p;
    var v = vec4<f32>(0.0);
    if (row < p.rows && c4 < p.ld4) {
        v = src[row * p.ld4 + c4];
    }
    textureStore(dst, texel(t), v);
}
