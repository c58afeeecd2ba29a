// Readout of a render's output: the requested region of each view, packed densely for the host to read with one
// copy (no row padding, no pixels outside the region), with a flag raised when any value read is NaN or
// infinite, so that the host never scans what it reads. The region's place and size change per render while
// the plan stays, so they come from a host-written buffer, not from the params.
//
// x is the output [views * height * width, cols] (rows padded to x_ld floats); out[i] for
// i = ((v * region_h + r) * region_w + c) * cols + j is x[(v * height + y + r) * width + x0 + c, j].

struct Params {
    views: u32,
    // The computed grid of each view.
    height: u32,
    width: u32,
    cols: u32,
    // Floats per row of x.
    x_ld: u32,
}

// The region inside the grid: its first row and column, its rows and columns (written by the host per render).
struct Window {
    y: u32,
    x: u32,
    h: u32,
    w: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;
@group(0) @binding(3) var<storage, read> window: Window;
@group(0) @binding(4) var<storage, read_write> flag: atomic<u32>;

@compute @workgroup_size(64)
fn read_region(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * 64u + lid;
    let per_view = window.h * window.w * p.cols;
    if (index >= p.views * per_view) {
        return;
    }
    let v = index / per_view;
    let pixel = (index % per_view) / p.cols;
    let j = index % p.cols;
    let r = pixel / window.w;
    let c = pixel % window.w;
    let value = x[((v * p.height + window.y + r) * p.width + window.x + c) * p.x_ld + j];
    out[index] = value;
    // NaN and infinity by their bits: a shader compiler may assume floats are finite and fold `value != value`.
    if ((bitcast<u32>(value) & 0x7f800000u) == 0x7f800000u) {
        atomicOr(&flag, 1u);
    }
}
