// Fourier positional encoding (the PositionalEncoding of SRT / RayPatchQuerying): for each output row, its
// coordinate row c (3 values) and the N multipliers m, writes
//   out[col + d*N + i] = sin(a), out[col + 3N + d*N + i] = cos(a), a = f32(c[d] * m[i]).
//
// The arguments reach |a| ~ 5e5 (2^14·π·|c|), where WGSL sets no accuracy for the built-in sin/cos (it
// bounds them only on [-π, π], to 2^-11), so sin_cos reduces the f32 argument explicitly:
// n = round(a·2/π), r = a - n·π/2 by a Cody-Waite scheme in which every product large enough to matter is
// exact, then the Cephes sinf/cosf minimax polynomials on r and the quadrant n mod 4. Exact products give
// the same result whether or not the compiler fuses them into an fma, so the scheme holds either way.
// Absolute error ≤ 1.2e-7 for |a| ≤ 2^20 (an f32 emulation of this operation order, fused or not, over
// every 11th f32 there and the f32 values nearest to each multiple of π/2). Beyond 2^20 it degrades
// gradually (round(a·2/π) drifts, so the polynomials see larger |r|).

struct Params {
    // Output rows in the view.
    rows: u32,
    // Output rows per coordinate row: coordinate row = (first_row + r) / repeat.
    repeat: u32,
    first_row: u32,
    // N, the number of multipliers.
    octaves: u32,
    // First output column this op writes.
    col: u32,
    // Output row stride in floats.
    ld: u32,
    // First padding column to zero (ld when this op does not write the last columns).
    pad_from: u32,
    // Always 0. XOR-ing the bits of c·m with it makes an integer op that the compiler cannot fold, so
    // c·m is rounded to f32 (as in torch) before the reduction: otherwise the compiler may fuse c·m into
    // the first subtraction of the reduction, an fma that skips that rounding.
    opaque_zero: u32,
    // The multipliers, m[i / 4][i % 4] (uniform arrays need a 16-byte element stride).
    m: array<vec4<f32>, 8>,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> coords: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

const TWO_OVER_PI: f32 = 0x1.45f306p-1f;
// π/2 = PIO2_1 + PIO2_2 + PIO2_3 + O(6e-18). PIO2_1 and PIO2_2 have 12 significant bits, so their
// products with integers below 2^12 (n_lo) or with 12-bit multiples of 4096 (n_hi) are exact for
// |n| < 2^24. PIO2_3 is the f32 rest: n·PIO2_3 ≤ 1e-3 for |n| < 2^20, so its rounding is negligible.
const PIO2_1: f32 = 0x1.922p0f;
const PIO2_2: f32 = -0x1.2aep-18f;
const PIO2_3: f32 = -0x1.de973ep-31f;
// Cephes sinf / cosf on [-π/4, π/4].
const S1: f32 = -1.6666654611e-1;
const S2: f32 = 8.3321608736e-3;
const S3: f32 = -1.9515295891e-4;
const C1: f32 = 4.166664568298827e-2;
const C2: f32 = -1.388731625493765e-3;
const C3: f32 = 2.443315711809948e-5;

// (sin(a), cos(a)) for an f32 argument.
fn sin_cos(a: f32) -> vec2<f32> {
    let n = round(a * TWO_OVER_PI);
    // n = n_hi + n_lo with n_hi a multiple of 4096 and |n_lo| < 4096, both of the sign of n (so the
    // partial differences below shrink monotonically: those that are large enough for their rounding to
    // matter are exact).
    let n_hi = trunc(n * (1.0 / 4096.0)) * 4096.0;
    let n_lo = n - n_hi;
    var r = a - n_hi * PIO2_1;
    r = r - n_lo * PIO2_1;
    r = r - n_hi * PIO2_2;
    r = r - n_lo * PIO2_2;
    r = r - n * PIO2_3;
    // a·2/π is rounded before round(), so |r| reaches 0.88 (> π/4) for |a| ≤ 2^20; the polynomials keep
    // ~1e-7 there.
    let z = r * r;
    let s = ((S3 * z + S2) * z + S1) * z * r + r;
    // cos in plain Horner form: a compiler may reassociate Cephes' (p·z² - z/2) + 1 into (p·z² + 1) - z/2,
    // which rounds twice near 1 (lavapipe does); Horner leaves nothing to reassociate.
    let c = (((C3 * z + C2) * z + C1) * z - 0.5) * z + 1.0;
    // a = r + q·π/2: q odd swaps to (cos r, -sin r); q = 2, 3 negate.
    let q = i32(n) & 3;
    let sc = select(vec2<f32>(s, c), vec2<f32>(c, -s), (q & 1) != 0);
    return select(sc, -sc, (q & 2) != 0);
}

@compute @workgroup_size(64)
fn fourier_encode(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let r = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (r >= p.rows) {
        return;
    }
    let c = coords[(p.first_row + r) / p.repeat];
    let row = r * p.ld;
    let n = p.octaves;
    for (var d = 0u; d < 3u; d++) {
        let sin_at = row + p.col + d * n;
        for (var i = 0u; i < n; i++) {
            let a = bitcast<f32>(bitcast<u32>(c[d] * p.m[i / 4u][i % 4u]) ^ p.opaque_zero);
            let sc = sin_cos(a);
            out[sin_at + i] = sc.x;
            out[sin_at + 3u * n + i] = sc.y;
        }
    }
    for (var j = p.pad_from; j < p.ld; j++) {
        out[row + j] = 0.0;
    }
}
