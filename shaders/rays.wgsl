// A pinhole camera's rays, one per pixel, made on the GPU from the host's column and row terms: the algorithm
// of crates/raypatch-model/src/pinhole.rs, step for step, so that these rays are bit-equal to the host's (read
// its documentation for why double-single arithmetic).
//
// terms holds, per view, `width` column terms R·[u_j, 0, 0] then `height` row terms R·[0, v_i, 1] (+ the
// camera centre for unit-depth points), each as hi (x, y, z, kind) then lo (x, y, z, 0): the kind
// (RAY_KIND_*) the view's terms were made for (the host makes a camera's rays of its own kind; a kind from
// anywhere else, the model's, would make other rays). The ray of pixel (v, i, j) is column j + row i,
// normalised when its kind is RAY_KIND_UNIT_DIRECTION, written to out[(v * height + i) * width + j, 0..3]
// (zeros in the row's padding).

// The kinds the terms carry: their values are raypatch_model::pinhole::gpu_kind_of's, which tests/uniforms.rs
// checks against these. Unit directions for SRT and OSRT, unit-depth points for DeFiNe.
const RAY_KIND_UNIT_DIRECTION: f32 = 0.0;
const RAY_KIND_UNIT_DEPTH_POINT: f32 = 1.0;

struct Params {
    views: u32,
    height: u32,
    width: u32,
    // Floats per row of terms and of out.
    terms_ld: u32,
    out_ld: u32,
    // 0, unknown to the compiler: see `opaque`.
    zero: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> terms: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

// hi + lo, |lo| at most half an ulp of hi.
struct Df {
    hi: f32,
    lo: f32,
}

// x, as a value the shader compiler cannot see into. WGSL has no `precise`: without this, a compiler may
// rewrite the error-free sums below by rules that hold only in exact arithmetic ((a + b) - a = b, which zeroes
// every error term), or fuse a rounded product into the sum after it (on lavapipe, a multiplication by an
// unknown 1.0 was not enough). Its bits through an integer xor with an unknown 0 block both.
fn opaque(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ p.zero);
}

// s + e = a + b exactly (Knuth).
fn two_sum(a: f32, b: f32) -> Df {
    let s = opaque(a + b);
    let bb = opaque(s - a);
    return Df(s, (a - (s - bb)) + (b - bb));
}

// s + e = a + b exactly for |a| >= |b|.
fn quick_two_sum(a: f32, b: f32) -> Df {
    let s = opaque(a + b);
    return Df(s, b - (s - a));
}

// hi + lo = a, each half with at most 12 significant bits (Dekker), so that products of halves are exact.
fn split(a: f32) -> Df {
    let t = opaque(4097.0 * a);
    let hi = t - opaque(t - a);
    return Df(hi, a - hi);
}

// p + e = a * b exactly (Dekker: a GPU's fma need not be fused, lavapipe's is not).
fn two_prod(a: f32, b: f32) -> Df {
    let q = opaque(a * b);
    let x = split(a);
    let y = split(b);
    // The products of halves are exact; the sums are kept in this order (Dekker's proof needs it).
    return Df(q, opaque(opaque(opaque(x.hi * y.hi - q) + x.hi * y.lo) + x.lo * y.hi) + x.lo * y.lo);
}

fn df_add(a: Df, b: Df) -> Df {
    let s = two_sum(a.hi, b.hi);
    let t = two_sum(a.lo, b.lo);
    let u = quick_two_sum(s.hi, s.lo + t.hi);
    return quick_two_sum(u.hi, u.lo + t.lo);
}

fn df_mul(a: Df, b: Df) -> Df {
    let q = two_prod(a.hi, b.hi);
    return quick_two_sum(q.hi, (opaque(a.hi * b.lo) + opaque(a.lo * b.hi)) + q.lo);
}

// 1/sqrt(x) for x >= 1: an integer estimate, three float32 Newton steps, two double-single ones.
fn df_inverse_sqrt(x: Df) -> Df {
    let half = 0.5 * x.hi;
    var r = bitcast<f32>(0x5f3759dfu - (bitcast<u32>(x.hi) >> 1u));
    for (var n = 0; n < 3; n++) {
        r = opaque(r * (1.5 - opaque(opaque(half * r) * r)));
    }
    var d = Df(r, 0.0);
    for (var n = 0; n < 2; n++) {
        let m = df_mul(x, df_mul(d, d));
        let e = df_add(Df(1.0, 0.0), Df(-m.hi, -m.lo));
        d = df_add(d, df_mul(d, Df(0.5 * e.hi, 0.5 * e.lo)));
    }
    return d;
}

fn term(row: u32, c: u32) -> Df {
    return Df(terms[row * p.terms_ld + c], terms[row * p.terms_ld + 4u + c]);
}

@compute @workgroup_size(64)
fn pinhole_rays(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * 64u + lid;
    let per_view = p.height * p.width;
    if (index >= p.views * per_view) {
        return;
    }
    let v = index / per_view;
    let i = (index % per_view) / p.width;
    let j = index % p.width;
    let column = v * (p.width + p.height) + j;
    let row = v * (p.width + p.height) + p.width + i;
    var w: array<Df, 3>;
    for (var c = 0u; c < 3u; c++) {
        w[c] = df_add(term(column, c), term(row, c));
    }
    // The kind of the view's camera, which every term of the view carries.
    if (terms[column * p.terms_ld + 3u] == RAY_KIND_UNIT_DIRECTION) {
        let n2 = df_add(df_add(df_mul(w[0], w[0]), df_mul(w[1], w[1])), df_mul(w[2], w[2]));
        let r = df_inverse_sqrt(n2);
        for (var c = 0u; c < 3u; c++) {
            w[c] = df_mul(w[c], r);
        }
    }
    for (var c = 0u; c < 3u; c++) {
        out[index * p.out_ld + c] = w[c].hi + w[c].lo;
    }
    for (var c = 3u; c < p.out_ld; c++) {
        out[index * p.out_ld + c] = 0.0;
    }
}
