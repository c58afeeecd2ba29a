// Image resizes as PyTorch's F.interpolate (antialias=False) on NHWC images: x [n*hi*wi, c] -> out [n*ho*wo, c]:
// bilinear (align_corners=False) for the patch rays and the rgb skips, nearest for the official output resize.
//
// One invocation per (output pixel, vec4 of channels). Input padding columns are zero, so the interpolated
// padding is zero too and whole vec4s are written.
//
// Source indices follow PyTorch's CPU and CUDA kernels, with scale = in/out computed in f32 by the host
// (a GPU division need not be correctly rounded):
// - bilinear: src = max(scale·(dst+0.5) − 0.5, 0), i0 = min(floor(src), in−1), i1 = min(i0+1, in−1),
//   λ = clamp(src − i0, 0, 1);
// - nearest: src = min(floor(dst·scale), in−1).

struct Params {
    hi: u32,
    wi: u32,
    ho: u32,
    wo: u32,
    // ld(c) / 4: vec4s per row of x and out.
    c4: u32,
    // n*ho*wo*c4: invocations that write.
    total: u32,
    scale_h: f32,
    scale_w: f32,
    // bilinear only: out += result instead of out = result.
    accumulate: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> out: array<vec4<f32>>;

const WG: u32 = 64u;

// The output element of this invocation: batch image b, output pixel (oy, ox), channel vec4 c.
struct Target {
    b: u32,
    oy: u32,
    ox: u32,
    c: u32,
}

fn locate(index: u32) -> Target {
    let pixel = index / p.c4;
    let ox = pixel % p.wo;
    let rows = pixel / p.wo;
    return Target(rows / p.ho, rows % p.ho, ox, index % p.c4);
}

struct Linear {
    i0: u32,
    i1: u32,
    lambda: f32,
}

fn linear_source(dst: u32, scale: f32, size: u32) -> Linear {
    let src = max(scale * (f32(dst) + 0.5) - 0.5, 0.0);
    let i0 = min(u32(floor(src)), size - 1u);
    return Linear(i0, min(i0 + 1u, size - 1u), clamp(src - f32(i0), 0.0, 1.0));
}

fn pixel(b: u32, y: u32, xx: u32, c: u32) -> vec4<f32> {
    return x[((b * p.hi + y) * p.wi + xx) * p.c4 + c];
}

@compute @workgroup_size(64)
fn bilinear(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * WG + lid;
    if (index >= p.total) {
        return;
    }
    let t = locate(index);
    let ys = linear_source(t.oy, p.scale_h, p.hi);
    let xs = linear_source(t.ox, p.scale_w, p.wi);
    let h1 = ys.lambda;
    let h0 = 1.0 - h1;
    let w1 = xs.lambda;
    let w0 = 1.0 - w1;
    // PyTorch's channels-last evaluation order, ((x00·w00 + x01·w01) + x10·w10) + x11·w11 with the weights
    // multiplied first. The official loader resizes the ray grid as a permuted (channels-last) tensor, and
    // the top ray octave (2^14·π) turns a 1-ulp difference in a patch ray into a visible one in the image;
    // with k a power of two the weights are powers of two, so this order reproduces PyTorch bit for bit.
    // (Other ratios, as for a target size k does not divide, have weights whose products round: PyTorch's
    // x86 build fuses them into fmas there, which WGSL cannot promise, so those patch rays may differ by an ulp.)
    var v = pixel(t.b, ys.i0, xs.i0, t.c) * (h0 * w0) + pixel(t.b, ys.i0, xs.i1, t.c) * (h0 * w1);
    v = v + pixel(t.b, ys.i1, xs.i0, t.c) * (h1 * w0);
    v = v + pixel(t.b, ys.i1, xs.i1, t.c) * (h1 * w1);
    if (p.accumulate != 0u) {
        v += out[index];
    }
    out[index] = v;
}

@compute @workgroup_size(64)
fn nearest(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * WG + lid;
    if (index >= p.total) {
        return;
    }
    let t = locate(index);
    let y = min(u32(floor(f32(t.oy) * p.scale_h)), p.hi - 1u);
    let xx = min(u32(floor(f32(t.ox) * p.scale_w)), p.wi - 1u);
    out[index] = pixel(t.b, y, xx, t.c);
}
