// Rows of x mixed by weights: out[r, :] = Σ_i w[r, i] · x[i, :], i.e. out = w · x for w [rows, n] and x [n, cols]
// (rows of out padded to ld4 vec4s, x likewise; w's rows are w_ld floats apart). This is the official
// MixingBlock's slot mix Σ_s w·slots and slot attention's updates attn·v: n (slots, or inputs) is small or
// the rows are few, so each invocation sums one vec4 of one output row over n in order.

struct Params {
    rows: u32,
    n: u32,
    // floats per row of w.
    w_ld: u32,
    // vec4s per row of x and out.
    ld4: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> w: array<f32>;
@group(0) @binding(2) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn mix_rows(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (index >= p.rows * p.ld4) {
        return;
    }
    let r = index / p.ld4;
    let c = index % p.ld4;
    // x's padding columns are zero, so out's are too.
    var acc = vec4<f32>(0.0);
    for (var i = 0u; i < p.n; i++) {
        acc += w[r * p.w_ld + i] * x[i * p.ld4 + c];
    }
    out[index] = acc;
}
