// 3×3 convolution, zero padding 1, stride 1 or 2, NHWC, with an optional 2× nearest upsampling of the input
// fused into the reads: out = act(conv(x) + bias), or out += act(conv(x) + bias) when accumulating.
//
// x: [n*h*w, cin] (padded to ld(cin) with zeros). w: [cout, 9*ld(cin)], for each output channel the 9 taps
// (ky, kx row-major), each ld(cin) input channels (see kernels::conv::pack_conv3x3). out: [n*ho*wo, cout].
// With upsampling the convolution sees the effective image 2h × 2w whose pixel (y, x) is x[y >> 1, x >> 1].
//
// Register blocking: each invocation computes PX = 8 consecutive output pixels of one row × CV = 2 vec4s of
// output channels, as 2 × 2 mat4x4 accumulators (a column per pixel, a row per channel). For each kernel
// row ky and each vec4 of input channels it loads the window of input pixels the 8 outputs' 3 taps cover
// (10 for stride 1, 17 for stride 2) once and reuses it across the 3 taps kx, so every loaded vec4 feeds
// 4 to 12 mat4x4 products. Lavapipe loads storage buffers lane by lane and component by component, so the
// loads, not the arithmetic, set the speed; the blocking minimises loads per multiply-add.
//
// Grid: a workgroup is 64 invocations along the pixel blocks sharing one tile of CV vec4s of channels;
// groups are numbered channel-tile-fastest, so consecutive groups reuse the same input pixels. The stride is
// a constant of each entry point (conv3x3_s1, conv3x3_s2), so the window size and tap offsets fold.

struct Params {
    h: u32,
    w: u32,
    // ld(cin) / 4: vec4s per row of x and per tap of w.
    cin4: u32,
    cout: u32,
    // ld(cout) / 4: vec4s per row of out.
    cout4: u32,
    ho: u32,
    wo: u32,
    // 1 when the input is upsampled 2× (nearest) before the convolution, else 0: a shift of the coordinates.
    up: u32,
    // 0 none, 1 relu, 2 leaky relu (slope).
    act: u32,
    slope: f32,
    has_bias: u32,
    accumulate: u32,
    // n*ho: output rows over the batch.
    rows: u32,
    // ceil(wo / PX): pixel blocks per output row.
    row_blocks: u32,
    // ceil(cout4 / CV): channel tiles, the fastest-varying part of the group index.
    cout_tiles: u32,
    // ceil(rows * row_blocks / 64): pixel-block tiles.
    block_tiles: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;
// [1, cout]; when there is no bias the wrapper binds w here and has_bias is 0.
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

const WG: u32 = 64u;
// Output pixels per invocation (consecutive in a row) and vec4s of output channels per invocation;
// kernels::conv mirrors them. The code below is written out for PX = 8 (2 pixel quads) and CV = 2.
const PX: u32 = 8u;
const CV: u32 = 2u;
// Window of effective input columns for stride 2: (PX - 1) * 2 + 3.
const WIN: u32 = 2u * PX + 1u;

// Accumulators: m{j}{q} holds channel quad j (4 output channels, rows) of pixel quad q (4 pixels, columns).
struct Acc {
    m00: mat4x4<f32>,
    m01: mat4x4<f32>,
    m10: mat4x4<f32>,
    m11: mat4x4<f32>,
}

fn activate(v: vec4<f32>) -> vec4<f32> {
    if (p.act == 1u) {
        return max(v, vec4<f32>(0.0));
    }
    if (p.act == 2u) {
        return select(v * p.slope, v, v >= vec4<f32>(0.0));
    }
    return v;
}

// The weights of 4 output channels (starts of their rows in w: `rows`) at offset k of each row, arranged so
// that multiplying it by a matrix of 4 input vec4s (columns) gives the 4 channels (rows) of each column.
fn weights(rows: vec4<u32>, k: u32) -> mat4x4<f32> {
    return transpose(mat4x4<f32>(w[rows.x + k], w[rows.y + k], w[rows.z + k], w[rows.w + k]));
}

// The 4 window entries pixel quad q reads at tap kx, as the columns of a matrix.
fn quad(win: ptr<function, array<vec4<f32>, WIN>>, s: u32, kx: u32, q: u32) -> mat4x4<f32> {
    let t = 4u * q * s + kx;
    return mat4x4<f32>((*win)[t], (*win)[t + s], (*win)[t + 2u * s], (*win)[t + 3u * s]);
}

// Adds tap kx (weights at offset k of each row) for both pixel quads and the channel quads in use.
fn tap(acc: ptr<function, Acc>, win: ptr<function, array<vec4<f32>, WIN>>, s: u32, kx: u32, k: u32,
       rows0: vec4<u32>, rows1: vec4<u32>, second: bool) {
    let x0 = quad(win, s, kx, 0u);
    let x1 = quad(win, s, kx, 1u);
    let w0 = weights(rows0, k);
    (*acc).m00 += w0 * x0;
    (*acc).m01 += w0 * x1;
    if (second) {
        let w1 = weights(rows1, k);
        (*acc).m10 += w1 * x0;
        (*acc).m11 += w1 * x1;
    }
}

// Bias, activation, accumulation and the store of one vec4 of channels of pixel quad q.
fn store(m: mat4x4<f32>, r: u32, ox0: u32, col: u32) {
    if (col >= p.cout4) {
        return;
    }
    var b = vec4<f32>(0.0);
    if (p.has_bias != 0u) {
        b = bias[col];
    }
    let real = vec4<u32>(4u * col) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(p.cout);
    for (var i = 0u; i < 4u; i++) {
        if (ox0 + i < p.wo) {
            let o = (r * p.wo + ox0 + i) * p.cout4 + col;
            var v = select(vec4<f32>(0.0), activate(m[i] + b), real);
            if (p.accumulate != 0u) {
                v += out[o];
            }
            out[o] = v;
        }
    }
}

fn conv(s: u32, wid: vec3<u32>, nwg: vec3<u32>, lid: u32) {
    let g = wid.x + wid.y * nwg.x;
    let tile = g / p.cout_tiles;
    if (tile >= p.block_tiles) {
        return;
    }
    let col0 = (g % p.cout_tiles) * CV;
    // Weight row starts of the 2 channel quads; channels past cout reuse the last row, and their results
    // are dropped in store(). The second quad is skipped (uniformly) when it is all padding.
    let last = vec4<u32>(p.cout - 1u);
    let stride_w = 9u * p.cin4;
    let rows0 = min(vec4<u32>(4u * col0) + vec4<u32>(0u, 1u, 2u, 3u), last) * stride_w;
    let rows1 = min(vec4<u32>(4u * col0 + 4u) + vec4<u32>(0u, 1u, 2u, 3u), last) * stride_w;
    let second = col0 + 1u < p.cout4;

    // This invocation's pixel block: output row r = b*ho + oy, pixels ox0 .. ox0 + PX - 1 (those >= wo are
    // computed from zeros and not stored). Blocks past the last row compute row 0 and store nothing.
    let block = tile * WG + lid;
    let r_raw = block / p.row_blocks;
    let r = min(r_raw, p.rows - 1u);
    let ox0 = (block % p.row_blocks) * PX;
    let img = (r / p.ho) * p.h;
    let oy = r % p.ho;
    let he = i32(p.h << p.up);
    let we = i32(p.w << p.up);
    let e0 = i32(ox0 * s) - 1;

    var acc: Acc;
    var win: array<vec4<f32>, WIN>;
    for (var ky = 0u; ky < 3u; ky++) {
        let ey = i32(oy * s + ky) - 1;
        let row_ok = ey >= 0 && ey < he;
        let row = (img + (u32(ey) >> p.up)) * p.w;
        let k = ky * 3u * p.cin4;
        for (var c = 0u; c < p.cin4; c++) {
            // Effective columns e0 + t; outside the image (the zero padding) read pixel 0 and select zero.
            for (var t = 0u; t < (PX - 1u) * s + 3u; t++) {
                let e = e0 + i32(t);
                let inside = row_ok && e >= 0 && e < we;
                let src = select(0u, (row + (u32(e) >> p.up)) * p.cin4 + c, inside);
                win[t] = select(vec4<f32>(0.0), x[src], inside);
            }
            tap(&acc, &win, s, 0u, k + c, rows0, rows1, second);
            tap(&acc, &win, s, 1u, k + p.cin4 + c, rows0, rows1, second);
            tap(&acc, &win, s, 2u, k + 2u * p.cin4 + c, rows0, rows1, second);
        }
    }

    if (r_raw >= p.rows) {
        return;
    }
    store(acc.m00, r, ox0, col0);
    store(acc.m01, r, ox0 + 4u, col0);
    store(acc.m10, r, ox0, col0 + 1u);
    store(acc.m11, r, ox0 + 4u, col0 + 1u);
}

@compute @workgroup_size(64)
fn conv3x3_s1(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    conv(1u, wid, nwg, lid);
}

@compute @workgroup_size(64)
fn conv3x3_s2(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    conv(2u, wid, nwg, lid);
}
