// Layer normalisation over the columns of each row (PyTorch nn.LayerNorm on the last dimension, biased
// variance): out[r] = (x[r] - mean) / sqrt(var + eps) * gamma + beta.
//
// One invocation per row, three passes over the row (sum, sum of squared deviations, output), vec4 loads.
// The statistics are taken of the deviations from the row's first element x0, and the mean is never
// rounded to f32 on its own: the output uses d = (x - x0) - delta with delta = sum(x - x0) / C. A row
// with mean 1e4 and std 1e-2 thus keeps the precision of its deviations (x - x0 is exact there), where an
// explicit f32 mean would be off by up to ulp(1e4) / 2 = 5e-4 = 5% of the std. A constant row gives d = 0
// and so exactly beta.

struct Params {
    rows: u32,
    cols: u32,
    // Row stride in vec4s.
    ld4: u32,
    eps: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> gamma: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> beta: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn layernorm(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let r = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (r >= p.rows) {
        return;
    }
    let row = r * p.ld4;
    // Vec4s whose 4 lanes are all columns, then the lanes of the last, partial vec4 that are columns.
    let full = p.cols / 4u;
    let in_tail = vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(p.cols % 4u);
    let has_tail = p.cols % 4u != 0u;
    let zero = vec4<f32>(0.0);
    let x0 = x[row].x;

    var s = zero;
    for (var k = 0u; k < full; k++) {
        s += x[row + k] - x0;
    }
    if (has_tail) {
        s += select(zero, x[row + full] - x0, in_tail);
    }
    let delta = (s.x + s.y + s.z + s.w) / f32(p.cols);

    var v = zero;
    for (var k = 0u; k < full; k++) {
        let d = (x[row + k] - x0) - delta;
        v += d * d;
    }
    if (has_tail) {
        let d = select(zero, (x[row + full] - x0) - delta, in_tail);
        v += d * d;
    }
    let rstd = 1.0 / sqrt((v.x + v.y + v.z + v.w) / f32(p.cols) + p.eps);

    for (var k = 0u; k < full; k++) {
        out[row + k] = ((x[row + k] - x0) - delta) * rstd * gamma[k] + beta[k];
    }
    if (has_tail) {
        let y = ((x[row + full] - x0) - delta) * rstd * gamma[full] + beta[full];
        out[row + full] = select(zero, y, in_tail);
    }
}
