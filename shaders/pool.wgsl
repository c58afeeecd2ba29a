// Max pooling as PyTorch's nn.MaxPool2d(kernel, stride, padding) (dilation 1, ceil_mode=False) on NHWC
// images: x [n*h*w, c] -> out [n*ho*wo, c], ho = (h + 2*pad - K) / stride + 1. The padding is −∞: a window
// takes the maximum of the pixels it covers inside the image (the wrapper keeps pad <= K/2, as PyTorch
// does, so every window covers one). A NaN in a window gives an unspecified result (WGSL's max).
//
// One invocation per (output pixel, vec4 of channels). Input padding columns are zero, so the padding
// columns of out are the maximum of zeros: whole vec4s are written.

struct Params {
    h: u32,
    w: u32,
    // ld(c) / 4: vec4s per row of x and out.
    c4: u32,
    ho: u32,
    wo: u32,
    // The window: K × K taps, stride, padding on every side.
    k: u32,
    stride: u32,
    pad: u32,
    // n*ho*wo*c4: invocations that write.
    total: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> out: array<vec4<f32>>;

const WG: u32 = 64u;

@compute @workgroup_size(64)
fn max_pool2d(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * WG + lid;
    if (index >= p.total) {
        return;
    }
    let c = index % p.c4;
    let pixel = index / p.c4;
    let ox = pixel % p.wo;
    let rows = pixel / p.wo;
    let oy = rows % p.ho;
    let img = (rows / p.ho) * p.h;

    // The window clipped to the image (the padding never wins a maximum).
    let y0 = i32(oy * p.stride) - i32(p.pad);
    let x0 = i32(ox * p.stride) - i32(p.pad);
    let y_lo = u32(max(y0, 0));
    let x_lo = u32(max(x0, 0));
    let y_hi = u32(min(y0 + i32(p.k), i32(p.h)));
    let x_hi = u32(min(x0 + i32(p.k), i32(p.w)));

    var m = x[((img + y_lo) * p.w + x_lo) * p.c4 + c];
    for (var iy = y_lo; iy < y_hi; iy++) {
        let row = (img + iy) * p.w;
        for (var ix = x_lo; ix < x_hi; ix++) {
            m = max(m, x[(row + ix) * p.c4 + c]);
        }
    }
    out[index] = m;
}
