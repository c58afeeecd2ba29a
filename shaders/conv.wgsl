// Square K×K convolution, any stride >= 1 and zero padding, NHWC, with an optional 2× nearest upsampling of
// the input fused into the reads. Three ways to meet what `out` holds (`mode`): out = act(conv(x) + bias)
// (overwrite), out += act(conv(x) + bias) (accumulate: the Ray-Patch rgb skips), or
// out = act(out + conv(x) + bias) (residual: torchvision BasicBlock's relu(bn2(conv2(.)) + identity)).
//
// x: [n*h*w, cin] (padded to ld(cin) with zeros). w: [cout, K*K*ld(cin)], for each output channel the K*K
// taps (ky, kx row-major), each ld(cin) input channels (see kernels::conv::pack_conv). out: [n*ho*wo, cout]
// with ho = (h_eff + 2*pad - K) / stride + 1 (PyTorch's), h_eff = h, or 2h with upsampling: the convolution
// then sees the effective image 2h × 2w whose pixel (y, x) is x[y >> 1, x >> 1].
// As an implicit GEMM: M = output pixels, N = cout, K = K*K taps × ld(cin).
//
// Register blocking: each invocation computes PX = 8 output pixels (64 apart in the flattened n*ho*wo order,
// so neighbouring lanes read neighbouring pixels and blocks never straddle row ends) × CV = 2 vec4s of output
// channels, as 2 × 2 mat4x4 accumulators (a column per pixel, a row per channel). Per tap and vec4 of input
// channels it loads 8 input vec4s and 8 weight vec4s for 256 multiply-adds. Lavapipe loads storage buffers
// lane by lane and component by component (even uniform addresses), so loads per multiply-add set the speed.
// Measured there (3×3): 8 × 16 channels runs ~10% faster but compiles 3× slower (~6 s); 16 pixels or reusing
// an input window across the taps of a row is no faster and compiles slower still. K, stride and padding
// are uniforms: on the model's 3×3 shapes this runs as fast as the loop over 9 constant taps did (process
// CPU time within ±3%, the noise; tests/kernels/conv_speed.rs). With few input channels (ResNet's stem,
// cin = 3 in one vec4 per tap) the per-tap setup weighs more: ~60% of the 3×3 convs' multiply-adds per second.
//
// Grid: a workgroup is 64 invocations along the pixels sharing one tile of CV vec4s of channels (the same
// weights for every lane: on GPUs they stay in cache); groups are numbered channel-tile-fastest, so
// consecutive groups reuse the same input pixels. The second channel quad is skipped (a uniform branch)
// when it lies past cout.

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
    // The window: K × K taps, stride, zero padding on every side of the (effective) image.
    k: u32,
    stride: u32,
    pad: u32,
    // 1 when the input is upsampled 2× (nearest) before the convolution, else 0: a shift of the coordinates.
    up: u32,
    // activation code and slope (shaders/activation.wgsl).
    act: u32,
    slope: f32,
    has_bias: u32,
    // 0: out = act(conv + b); 1: out += act(conv + b); 2: out = act(out + conv + b) (kernels::conv::ConvMode).
    mode: u32,
    // n*ho*wo.
    npix: u32,
    // Channel tiles, the fastest-varying part of the group index: ceil(cout4 / CV) for `conv2d`,
    // ceil(cout4 / (TILE / 4)) for `conv_tiled`.
    cout_tiles: u32,
    // Pixel tiles: ceil(npix / (64 * PX)) for `conv2d`, ceil(npix / TILE) for `conv_tiled`.
    pixel_tiles: u32,
    // `conv_tiled` only: the weight row (K) cut into `splits` ranges of k_split4 vec4s (a multiple of TILE_K4), one
    // per workgroup, when the output's tiles are too few to fill a GPU; `conv_reduce` adds them up.
    splits: u32,
    k_split4: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;
// [1, cout]; when there is no bias the wrapper binds w here and has_bias is 0.
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

const WG: u32 = 64u;
// Output pixels and vec4s of output channels per invocation; kernels::conv mirrors them. The accumulators
// and the channel-quad code below are written out for these values.
const PX: u32 = 8u;
const CV: u32 = 2u;

// m{j}{q}: channel quad j (4 output channels, the rows) of pixel quad q (4 pixels, the columns).
struct Acc {
    m00: mat4x4<f32>,
    m01: mat4x4<f32>,
    m10: mat4x4<f32>,
    m11: mat4x4<f32>,
}

// Starts in w of the rows of channel quad j of this tile; channels past cout reuse the last row (their
// results are dropped when storing).
fn weight_rows(col0: u32, j: u32) -> vec4<u32> {
    let co = vec4<u32>(4u * (col0 + j)) + vec4<u32>(0u, 1u, 2u, 3u);
    return min(co, vec4<u32>(p.cout - 1u)) * (p.k * p.k * p.cin4);
}

// The weights of 4 output channels at offset k of their rows, arranged so that multiplying the matrix of
// 4 input vec4s (columns) gives the 4 channels (rows) of each column.
fn weights(rows: vec4<u32>, k: u32) -> mat4x4<f32> {
    return transpose(mat4x4<f32>(w[rows.x + k], w[rows.y + k], w[rows.z + k], w[rows.w + k]));
}

// Bias, residual, activation, accumulation and the store of channel vec4 `col` of pixel `pix` (nothing past
// the end of either).
fn store_one(v: vec4<f32>, pix: u32, col: u32) {
    if (col >= p.cout4 || pix >= p.npix) {
        return;
    }
    var b = vec4<f32>(0.0);
    if (p.has_bias != 0u) {
        b = bias[col];
    }
    let real = vec4<u32>(4u * col) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(p.cout);
    let o = pix * p.cout4 + col;
    var prior = vec4<f32>(0.0);
    if (p.mode != MODE_OVERWRITE) {
        prior = out[o];
    }
    out[o] = epilogue(v + b, prior, p.mode, p.act, p.slope, real);
}

// The store of channel vec4 `col` of the 4 pixels pix0 + 64 i (columns of m).
fn store(m: mat4x4<f32>, pix0: u32, col: u32) {
    for (var i = 0u; i < 4u; i++) {
        store_one(m[i], pix0 + i * WG, col);
    }
}

@compute @workgroup_size(64)
fn conv2d(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let g = wid.x + wid.y * nwg.x;
    let tile = g / p.cout_tiles;
    if (tile >= p.pixel_tiles) {
        return;
    }
    let col0 = (g % p.cout_tiles) * CV;
    let rows0 = weight_rows(col0, 0u);
    let rows1 = weight_rows(col0, 1u);

    // This invocation's pixels pix0 + 64 i: the row of their batch image in x (b*h) and their top-left tap
    // in the effective image. Pixels past npix compute pixel npix - 1 and store nothing.
    let pix0 = tile * WG * PX + lid;
    var img: array<u32, PX>;
    var iy0: array<i32, PX>;
    var ix0: array<i32, PX>;
    for (var i = 0u; i < PX; i++) {
        let q = min(pix0 + i * WG, p.npix - 1u);
        let r = q / p.wo;
        img[i] = (r / p.ho) * p.h;
        iy0[i] = i32((r % p.ho) * p.stride) - i32(p.pad);
        ix0[i] = i32((q % p.wo) * p.stride) - i32(p.pad);
    }
    let he = i32(p.h << p.up);
    let we = i32(p.w << p.up);

    var acc: Acc;
    // The offset of the tap in each weight row.
    var tap_start = 0u;
    for (var ky = 0u; ky < p.k; ky++) {
        for (var kx = 0u; kx < p.k; kx++) {
            // Each pixel's input pixel for this tap; in the zero padding read pixel 0 and select zero.
            var src: array<u32, PX>;
            var inside: array<bool, PX>;
            for (var i = 0u; i < PX; i++) {
                let iy = iy0[i] + i32(ky);
                let ix = ix0[i] + i32(kx);
                inside[i] = iy >= 0 && iy < he && ix >= 0 && ix < we;
                src[i] = select(0u, ((img[i] + (u32(iy) >> p.up)) * p.w + (u32(ix) >> p.up)) * p.cin4, inside[i]);
            }
            for (var c = 0u; c < p.cin4; c++) {
                var xv: array<vec4<f32>, PX>;
                for (var i = 0u; i < PX; i++) {
                    xv[i] = select(vec4<f32>(0.0), x[src[i] + c], inside[i]);
                }
                let x0 = mat4x4<f32>(xv[0], xv[1], xv[2], xv[3]);
                let x1 = mat4x4<f32>(xv[4], xv[5], xv[6], xv[7]);
                let w0 = weights(rows0, tap_start + c);
                acc.m00 += w0 * x0;
                acc.m01 += w0 * x1;
                if (col0 + 1u < p.cout4) {
                    let w1 = weights(rows1, tap_start + c);
                    acc.m10 += w1 * x0;
                    acc.m11 += w1 * x1;
                }
            }
            tap_start += p.cin4;
        }
    }

    store(acc.m00, pix0, col0);
    store(acc.m01, pix0 + 4u * WG, col0);
    store(acc.m10, pix0, col0 + 1u);
    store(acc.m11, pix0 + 4u * WG, col0 + 1u);
}

// `conv_tiled`: the same convolution as an implicit GEMM in workgroup-memory tiles, for GPUs (tiles.wgsl, the
// tiling of matmul.wgsl's `linear_tiled`; tiles.wgsl says why these sizes and layouts): a workgroup of 16 x 16
// invocations computes TILE output pixels x TILE output channels (128), invocation (tx, ty) pixels
// block_row(ty, i) and the channels of vec4 columns block_col4(tx, j). K is the weight row, taps x cin4 vec4s (tap-major, as
// pack_conv lays it out), walked TILE_K4 vec4s at a time whatever the tap boundaries, so that few input
// channels (ResNet's RGB stem, one vec4 a tap) waste no steps. Each step gathers TILE pixels' input vec4s (the
// im2col of the tile, never materialised: the tap's offset, the zero padding and the 2x nearest upsampling
// resolved per load) and TILE channels' weight vec4s into workgroup memory; the next step's are loaded into
// registers while the staged one is multiplied.

// Where one output pixel's window starts: its image's first row in x (b*h) and its top-left tap in the
// effective image (may be negative: padding).
struct Window {
    img: u32,
    iy0: i32,
    ix0: i32,
}

fn window_of(pix: u32) -> Window {
    let q = min(pix, p.npix - 1u);
    let r = q / p.wo;
    return Window((r / p.ho) * p.h, i32((r % p.ho) * p.stride) - i32(p.pad), i32((q % p.wo) * p.stride) - i32(p.pad));
}

// Vec4 `kk` of the weight row (tap kk / cin4, channels kk % cin4) for the pixel's window; zero in the padding.
fn gather(win: Window, kk: u32) -> vec4<f32> {
    let tap = kk / p.cin4;
    let iy = win.iy0 + i32(tap / p.k);
    let ix = win.ix0 + i32(tap % p.k);
    if (iy < 0 || iy >= i32(p.h << p.up) || ix < 0 || ix >= i32(p.w << p.up)) {
        return vec4<f32>(0.0);
    }
    return x[((win.img + (u32(iy) >> p.up)) * p.w + (u32(ix) >> p.up)) * p.cin4 + kk % p.cin4];
}

// The step at vec4 `at` of the weight row for the pixel's window `win` and of w's row at `wa`; zeros past k_end.
fn gather_step(at: u32, k_end: u32, win: Window, wa: u32) -> Staged {
    if (at >= k_end) {
        return Staged();
    }
    return Staged(gather(win, at), w[wa + at]);
}

// Stores vec4 `v` of the block at output pixel `pix`, vec4 channel `col`: finished (store_one), or raw into split's
// range of the partials.
fn store_sum(pix: u32, col: u32, split: u32, v: vec4<f32>) {
    if (p.splits == 1u) {
        store_one(v, pix, col);
    } else if (pix < p.npix && col < p.cout4) {
        out[(split * p.npix + pix) * p.cout4 + col] = v;
    }
}

@compute @workgroup_size(16, 16)
fn conv_tiled(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let group = wid.x + wid.y * nwg.x;
    let tile = group % p.cout_tiles;
    let rest = group / p.cout_tiles;
    let pix0 = (rest % p.pixel_tiles) * TILE;
    let split = rest / p.pixel_tiles;
    // The same for every invocation of the workgroup, so the barriers below stay in uniform control flow.
    if (split >= p.splits) {
        return;
    }
    // This invocation loads row li / TILE_K4 of both tiles (a pixel, and an output channel), at vec4 kk of each
    // step. Channels past cout reuse the last one (their results are dropped).
    let kk = li % TILE_K4;
    let win = window_of(pix0 + li / TILE_K4);
    let k4 = p.k * p.k * p.cin4;
    let k_begin = split * p.k_split4;
    let k_end = min(k4, k_begin + p.k_split4);
    let wa = min(tile * TILE + li / TILE_K4, p.cout - 1u) * k4;
    var next = gather_step(k_begin + kk, k_end, win, wa);
    // This invocation's block of out (tiles.wgsl), in registers: named variables (gen_tiles.py says why).
    // BEGIN sums: written by tools/codegen/gen_tiles.py
    var sums_0 = vec4<f32>(0.0);
    var sums_1 = vec4<f32>(0.0);
    var sums_2 = vec4<f32>(0.0);
    var sums_3 = vec4<f32>(0.0);
    var sums_4 = vec4<f32>(0.0);
    var sums_5 = vec4<f32>(0.0);
    var sums_6 = vec4<f32>(0.0);
    var sums_7 = vec4<f32>(0.0);
    var sums_8 = vec4<f32>(0.0);
    var sums_9 = vec4<f32>(0.0);
    var sums_10 = vec4<f32>(0.0);
    var sums_11 = vec4<f32>(0.0);
    var sums_12 = vec4<f32>(0.0);
    var sums_13 = vec4<f32>(0.0);
    var sums_14 = vec4<f32>(0.0);
    var sums_15 = vec4<f32>(0.0);
    // END sums
    for (var k0 = k_begin; k0 < k_end; k0 += TILE_K4) {
        stage_step(li, next);
        workgroupBarrier();
        next = gather_step(k0 + TILE_K4 + kk, k_end, win, wa);
        // BEGIN multiply_staged: written by tools/codegen/gen_tiles.py
        {
            let a0 = x_tile[0u + lid.y];
            let a1 = x_tile[16u + lid.y];
            let b0 = vec4<f32>(w_tile[0u + lid.x]);
            let b1 = vec4<f32>(w_tile[16u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[32u + lid.y];
            let a1 = x_tile[48u + lid.y];
            let b0 = vec4<f32>(w_tile[32u + lid.x]);
            let b1 = vec4<f32>(w_tile[48u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[64u + lid.y];
            let a1 = x_tile[80u + lid.y];
            let b0 = vec4<f32>(w_tile[64u + lid.x]);
            let b1 = vec4<f32>(w_tile[80u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[96u + lid.y];
            let a1 = x_tile[112u + lid.y];
            let b0 = vec4<f32>(w_tile[96u + lid.x]);
            let b1 = vec4<f32>(w_tile[112u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[128u + lid.y];
            let a1 = x_tile[144u + lid.y];
            let b0 = vec4<f32>(w_tile[128u + lid.x]);
            let b1 = vec4<f32>(w_tile[144u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[160u + lid.y];
            let a1 = x_tile[176u + lid.y];
            let b0 = vec4<f32>(w_tile[160u + lid.x]);
            let b1 = vec4<f32>(w_tile[176u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[192u + lid.y];
            let a1 = x_tile[208u + lid.y];
            let b0 = vec4<f32>(w_tile[192u + lid.x]);
            let b1 = vec4<f32>(w_tile[208u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        {
            let a0 = x_tile[224u + lid.y];
            let a1 = x_tile[240u + lid.y];
            let b0 = vec4<f32>(w_tile[224u + lid.x]);
            let b1 = vec4<f32>(w_tile[240u + lid.x]);
            sums_0 = fma(vec4<f32>(f32(a0.x)), b0, sums_0);
            sums_1 = fma(vec4<f32>(f32(a0.x)), b1, sums_1);
            sums_2 = fma(vec4<f32>(f32(a0.y)), b0, sums_2);
            sums_3 = fma(vec4<f32>(f32(a0.y)), b1, sums_3);
            sums_4 = fma(vec4<f32>(f32(a0.z)), b0, sums_4);
            sums_5 = fma(vec4<f32>(f32(a0.z)), b1, sums_5);
            sums_6 = fma(vec4<f32>(f32(a0.w)), b0, sums_6);
            sums_7 = fma(vec4<f32>(f32(a0.w)), b1, sums_7);
            sums_8 = fma(vec4<f32>(f32(a1.x)), b0, sums_8);
            sums_9 = fma(vec4<f32>(f32(a1.x)), b1, sums_9);
            sums_10 = fma(vec4<f32>(f32(a1.y)), b0, sums_10);
            sums_11 = fma(vec4<f32>(f32(a1.y)), b1, sums_11);
            sums_12 = fma(vec4<f32>(f32(a1.z)), b0, sums_12);
            sums_13 = fma(vec4<f32>(f32(a1.z)), b1, sums_13);
            sums_14 = fma(vec4<f32>(f32(a1.w)), b0, sums_14);
            sums_15 = fma(vec4<f32>(f32(a1.w)), b1, sums_15);
        }
        // END multiply_staged
        workgroupBarrier();
    }
    let first_row = pix0;
    let first_c4 = tile * (TILE / 4u);
    // BEGIN stores: written by tools/codegen/gen_tiles.py
    store_sum(first_row + block_row(lid.y, 0u), first_c4 + block_col4(lid.x, 0u), split, sums_0);
    store_sum(first_row + block_row(lid.y, 0u), first_c4 + block_col4(lid.x, 1u), split, sums_1);
    store_sum(first_row + block_row(lid.y, 1u), first_c4 + block_col4(lid.x, 0u), split, sums_2);
    store_sum(first_row + block_row(lid.y, 1u), first_c4 + block_col4(lid.x, 1u), split, sums_3);
    store_sum(first_row + block_row(lid.y, 2u), first_c4 + block_col4(lid.x, 0u), split, sums_4);
    store_sum(first_row + block_row(lid.y, 2u), first_c4 + block_col4(lid.x, 1u), split, sums_5);
    store_sum(first_row + block_row(lid.y, 3u), first_c4 + block_col4(lid.x, 0u), split, sums_6);
    store_sum(first_row + block_row(lid.y, 3u), first_c4 + block_col4(lid.x, 1u), split, sums_7);
    store_sum(first_row + block_row(lid.y, 4u), first_c4 + block_col4(lid.x, 0u), split, sums_8);
    store_sum(first_row + block_row(lid.y, 4u), first_c4 + block_col4(lid.x, 1u), split, sums_9);
    store_sum(first_row + block_row(lid.y, 5u), first_c4 + block_col4(lid.x, 0u), split, sums_10);
    store_sum(first_row + block_row(lid.y, 5u), first_c4 + block_col4(lid.x, 1u), split, sums_11);
    store_sum(first_row + block_row(lid.y, 6u), first_c4 + block_col4(lid.x, 0u), split, sums_12);
    store_sum(first_row + block_row(lid.y, 6u), first_c4 + block_col4(lid.x, 1u), split, sums_13);
    store_sum(first_row + block_row(lid.y, 7u), first_c4 + block_col4(lid.x, 0u), split, sums_14);
    store_sum(first_row + block_row(lid.y, 7u), first_c4 + block_col4(lid.x, 1u), split, sums_15);
    // END stores
}

// `conv_reduce`: the K ranges of a split `conv_tiled` added up and finished into out (store_one: bias, residual,
// activation, accumulation), an invocation per vec4 of out. Bindings as for the other entry points, the
// partials ([splits * npix, cout4] vec4s) in place of x (w is not read).
@compute @workgroup_size(64)
fn conv_reduce(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    _ = w[0];
    let index = (wid.x + wid.y * nwg.x) * WG + lid;
    if (index >= p.npix * p.cout4) {
        return;
    }
    let pix = index / p.cout4;
    let col = index % p.cout4;
    var sum = vec4<f32>(0.0);
    for (var s = 0u; s < p.splits; s++) {
        sum += x[(s * p.npix + pix) * p.cout4 + col];
    }
    store_one(sum, pix, col);
}
