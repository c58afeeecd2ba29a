// 3×3 convolution, zero padding 1, stride 1 or 2, NHWC, with an optional 2× nearest upsampling of the input
// fused into the reads: out = act(conv(x) + bias), or out += act(conv(x) + bias) when accumulating.
//
// x: [n*h*w, cin] (padded to ld(cin) with zeros). w: [cout, 9*ld(cin)], for each output channel the 9 taps
// (ky, kx row-major), each ld(cin) input channels (see kernels::conv::pack_conv3x3). out: [n*ho*wo, cout].
// As an implicit GEMM: M = output pixels, N = cout, K = 9 taps × ld(cin).
//
// Each invocation computes PX output pixels (64 apart) × CV vec4s of output channels. A workgroup is 64
// invocations along the pixels sharing one tile of CV vec4s of channels, so the weight loads are uniform
// across the workgroup (lavapipe turns them into broadcasts) and only the input loads differ per lane.
// Groups are numbered channel-tile-fastest, so consecutive groups reuse the same input pixels. Taps that
// fall in the zero padding read pixel 0 and select zero instead of branching.

struct Params {
    n: u32,
    h: u32,
    w: u32,
    // ld(cin) / 4: vec4s per row of x and per tap of w.
    cin4: u32,
    cout: u32,
    // ld(cout) / 4: vec4s per row of out.
    cout4: u32,
    ho: u32,
    wo: u32,
    stride: u32,
    // 1 when the input is upsampled 2× (nearest) before the convolution, else 0: a shift of the coordinates.
    up: u32,
    // 0 none, 1 relu, 2 leaky relu (slope).
    act: u32,
    slope: f32,
    has_bias: u32,
    accumulate: u32,
    // n*ho*wo.
    npix: u32,
    // ceil(cout4 / CV): channel tiles, the fastest-varying part of the group index.
    cout_tiles: u32,
    // ceil(npix / (64*PX)).
    pixel_tiles: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;
// [1, cout]; when there is no bias the wrapper binds w here and has_bias is 0.
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

const WG: u32 = 64u;
// Output pixels per invocation and vec4s of output channels per invocation; kernels::conv mirrors them.
const PX: u32 = 2u;
const CV: u32 = 3u;

fn activate(v: vec4<f32>) -> vec4<f32> {
    if (p.act == 1u) {
        return max(v, vec4<f32>(0.0));
    }
    if (p.act == 2u) {
        return select(v * p.slope, v, v >= vec4<f32>(0.0));
    }
    return v;
}

@compute @workgroup_size(64)
fn conv3x3(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let g = wid.x + wid.y * nwg.x;
    let tile = g / p.cout_tiles;
    if (tile >= p.pixel_tiles) {
        return;
    }
    let col0 = (g % p.cout_tiles) * CV;

    // Start (in vec4s) of each of the 4*CV weight rows; channels past cout reuse the last row, and their
    // results are dropped at the end.
    var wrow: array<u32, 4 * CV>;
    for (var j = 0u; j < 4u * CV; j++) {
        wrow[j] = min(col0 * 4u + j, p.cout - 1u) * 9u * p.cin4;
    }

    // This invocation's pixels: batch image row offset b*h, and the top-left tap in the (upsampled) input.
    var pix: array<u32, PX>;
    var img_row: array<u32, PX>;
    var iy0: array<i32, PX>;
    var ix0: array<i32, PX>;
    for (var i = 0u; i < PX; i++) {
        pix[i] = (tile * PX + i) * WG + lid;
        let q = min(pix[i], p.npix - 1u);
        let ox = q % p.wo;
        let r = q / p.wo;
        img_row[i] = (r / p.ho) * p.h;
        iy0[i] = i32((r % p.ho) * p.stride) - 1;
        ix0[i] = i32(ox * p.stride) - 1;
    }
    let he = i32(p.h << p.up);
    let we = i32(p.w << p.up);

    var acc: array<vec4<f32>, PX * CV>;
    for (var tap = 0u; tap < 9u; tap++) {
        let ky = i32(tap / 3u);
        let kx = i32(tap % 3u);
        var xrow: array<u32, PX>;
        var inside: array<bool, PX>;
        for (var i = 0u; i < PX; i++) {
            let iy = iy0[i] + ky;
            let ix = ix0[i] + kx;
            inside[i] = iy >= 0 && iy < he && ix >= 0 && ix < we;
            let src = (img_row[i] + (u32(iy) >> p.up)) * p.w + (u32(ix) >> p.up);
            xrow[i] = select(0u, src * p.cin4, inside[i]);
        }
        let wtap = tap * p.cin4;
        for (var c = 0u; c < p.cin4; c++) {
            var xv: array<vec4<f32>, PX>;
            for (var i = 0u; i < PX; i++) {
                xv[i] = select(vec4<f32>(0.0), x[xrow[i] + c], inside[i]);
            }
            for (var j = 0u; j < CV; j++) {
                let wm = mat4x4<f32>(w[wrow[4u * j] + wtap + c], w[wrow[4u * j + 1u] + wtap + c],
                                     w[wrow[4u * j + 2u] + wtap + c], w[wrow[4u * j + 3u] + wtap + c]);
                for (var i = 0u; i < PX; i++) {
                    // Row vector times matrix: the dot products of xv with the 4 weight rows.
                    acc[i * CV + j] += xv[i] * wm;
                }
            }
        }
    }

    for (var j = 0u; j < CV; j++) {
        let col = col0 + j;
        if (col >= p.cout4) {
            break;
        }
        var b = vec4<f32>(0.0);
        if (p.has_bias != 0u) {
            b = bias[col];
        }
        let real = vec4<u32>(4u * col) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(p.cout);
        for (var i = 0u; i < PX; i++) {
            if (pix[i] < p.npix) {
                let o = pix[i] * p.cout4 + col;
                var v = select(vec4<f32>(0.0), activate(acc[i * CV + j] + b), real);
                if (p.accumulate != 0u) {
                    v += out[o];
                }
                out[o] = v;
            }
        }
    }
}
