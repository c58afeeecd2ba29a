// Linear layer: out = act(x · wᵀ + bias), or out += act(x · wᵀ + bias) when accumulating.
//
// x: [M, K] rows, w: [N, K] rows (nn.Linear layout), both padded with zeros to ld(K), so the K loop runs
// over whole vec4s. Each invocation computes a 4x4 block of out: 4 rows of x against 4 rows of w, 16 dot
// products per vec4 step along K, written back as 4 vec4s (one per row), padding columns included.
//
// Grid: a workgroup is 64 invocations stacked along M (256 rows) sharing one 4-column tile of w, so the
// w loads are uniform across the workgroup (lavapipe turns them into broadcasts) and only the x loads
// differ per lane. Groups are numbered n-tile-fastest, so consecutive groups reuse the same x rows.

struct Params {
    m: u32,
    n: u32,
    // ld(K) / 4: vec4s per row of x and w.
    k4: u32,
    // ld(N) / 4: vec4s per row of out, which is also the number of 4-column tiles.
    n4: u32,
    // 0 none, 1 relu, 2 leaky relu (slope), 3 gelu (erf form).
    act: u32,
    slope: f32,
    has_bias: u32,
    accumulate: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;
// [1, N]; when there is no bias the wrapper binds w here and has_bias is 0.
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

const WG: u32 = 64u;
const TM: u32 = 4u;

// erf for f32, from FreeBSD's s_erff.c (Sun Microsystems, 1993; freely redistributable): rational
// approximations on [0, 0.84375), [0.84375, 1.25) and [1.25, 4), and ±1 beyond, where |1 - erf| < 1.6e-8.
// The erfc tail is exp(-x² - 0.5625 + R/S) / x; fdlibm splits x² to keep erfc's relative error small,
// which an absolute error target does not need. Measured max |error| against float64 erf: see
// tests/kernels/matmul.rs (gelu_erf_accuracy).
fn erf_abs(a: f32) -> f32 {
    if (a < 0.84375) {
        let z = a * a;
        let r = 1.2837916613e-01 + z * (-3.2504209876e-01 + z * (-2.8481749818e-02
            + z * (-5.7702702470e-03 + z * -2.3763017452e-05)));
        let s = 1.0 + z * (3.9791721106e-01 + z * (6.5022252500e-02 + z * (5.0813062117e-03
            + z * (1.3249473704e-04 + z * -3.9602282413e-06))));
        return a + a * (r / s);
    }
    if (a < 1.25) {
        let s = a - 1.0;
        let pa = -2.3621185683e-03 + s * (4.1485610604e-01 + s * (-3.7220788002e-01 + s * (3.1834661961e-01
            + s * (-1.1089469492e-01 + s * (3.5478305072e-02 + s * -2.1663755178e-03)))));
        let qa = 1.0 + s * (1.0642088205e-01 + s * (5.4039794207e-01 + s * (7.1828655899e-02
            + s * (1.2617121637e-01 + s * (1.3637083583e-02 + s * 1.1984500103e-02)))));
        return 8.4506291151e-01 + pa / qa;
    }
    if (a >= 4.0) {
        return 1.0;
    }
    let s = 1.0 / (a * a);
    var r: f32;
    var q: f32;
    if (a < 2.857142857) {
        r = -9.8649440333e-03 + s * (-6.9385856390e-01 + s * (-1.0558626175e+01 + s * (-6.2375331879e+01
            + s * (-1.6239666748e+02 + s * (-1.8460508728e+02 + s * (-8.1287437439e+01 + s * -9.8143291473e+00))))));
        q = 1.0 + s * (1.9651271820e+01 + s * (1.3765776062e+02 + s * (4.3456588745e+02 + s * (6.4538726807e+02
            + s * (4.2900814819e+02 + s * (1.0863500214e+02 + s * (6.5702495575e+00 + s * -6.0424413532e-02)))))));
    } else {
        r = -9.8649431020e-03 + s * (-7.9928326607e-01 + s * (-1.7757955551e+01 + s * (-1.6063638306e+02
            + s * (-6.3756646729e+02 + s * (-1.0250950928e+03 + s * -4.8351919556e+02)))));
        q = 1.0 + s * (3.0338060379e+01 + s * (3.2579251099e+02 + s * (1.5367296143e+03 + s * (3.1998581543e+03
            + s * (2.5530502930e+03 + s * (4.7452853394e+02 + s * -2.2440952301e+01))))));
    }
    return 1.0 - exp(-a * a - 0.5625 + r / q) / a;
}

fn erf(v: f32) -> f32 {
    return sign(v) * erf_abs(abs(v));
}

fn activate(v: vec4<f32>) -> vec4<f32> {
    switch p.act {
        case 1u: {
            return max(v, vec4<f32>(0.0));
        }
        case 2u: {
            return select(p.slope * v, v, v >= vec4<f32>(0.0));
        }
        case 3u: {
            let e = vec4<f32>(erf(v.x * 0.70710678), erf(v.y * 0.70710678), erf(v.z * 0.70710678),
                              erf(v.w * 0.70710678));
            return (0.5 * v) * (1.0 + e);
        }
        default: {
            return v;
        }
    }
}

// Finishes one row of the block: bias, activation, zeroed padding columns, accumulate, store.
fn store_row(row: u32, c4: u32, acc: vec4<f32>) {
    if (row >= p.m) {
        return;
    }
    var v = acc;
    if (p.has_bias != 0u) {
        v += bias[c4];
    }
    let cols = vec4<u32>(4u * c4) + vec4<u32>(0u, 1u, 2u, 3u);
    v = select(vec4<f32>(0.0), activate(v), cols < vec4<u32>(p.n));
    let at = row * p.n4 + c4;
    if (p.accumulate != 0u) {
        v += out[at];
    }
    out[at] = v;
}

@compute @workgroup_size(64)
fn linear(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_index) lid: u32) {
    let group = wid.x + wid.y * nwg.x;
    let c4 = group % p.n4;
    let row0 = ((group / p.n4) * WG + lid) * TM;
    if (row0 >= p.m) {
        return;
    }
    // Rows past the end of x or w are clamped to the last one; their results are discarded or zeroed.
    let last_m = p.m - 1u;
    let last_n = p.n - 1u;
    let x0 = row0 * p.k4;
    let x1 = min(row0 + 1u, last_m) * p.k4;
    let x2 = min(row0 + 2u, last_m) * p.k4;
    let x3 = min(row0 + 3u, last_m) * p.k4;
    let w0 = min(4u * c4, last_n) * p.k4;
    let w1 = min(4u * c4 + 1u, last_n) * p.k4;
    let w2 = min(4u * c4 + 2u, last_n) * p.k4;
    let w3 = min(4u * c4 + 3u, last_n) * p.k4;
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var k = 0u; k < p.k4; k++) {
        let b0 = w[w0 + k];
        let b1 = w[w1 + k];
        let b2 = w[w2 + k];
        let b3 = w[w3 + k];
        let a0 = x[x0 + k];
        let a1 = x[x1 + k];
        let a2 = x[x2 + k];
        let a3 = x[x3 + k];
        acc0 += vec4<f32>(dot(a0, b0), dot(a0, b1), dot(a0, b2), dot(a0, b3));
        acc1 += vec4<f32>(dot(a1, b0), dot(a1, b1), dot(a1, b2), dot(a1, b3));
        acc2 += vec4<f32>(dot(a2, b0), dot(a2, b1), dot(a2, b2), dot(a2, b3));
        acc3 += vec4<f32>(dot(a3, b0), dot(a3, b1), dot(a3, b2), dot(a3, b3));
    }
    store_row(row0, c4, acc0);
    store_row(row0 + 1u, c4, acc1);
    store_row(row0 + 2u, c4, acc2);
    store_row(row0 + 3u, c4, acc3);
}
