// Layer normalisation over the columns of each row (PyTorch nn.LayerNorm on the last dimension, biased
// variance): out[r] = (x[r] - mean) / sqrt(var + eps) * gamma + beta.
//
// Two ways to run it (device::norm_variant): `layernorm`, one invocation per row (CPU adapters, whose
// invocations are SIMD lanes), and on GPUs a workgroup per row, `layernorm_wide` and `row_stats`: 64
// invocations take every 64th vec4 of the row and add their sums up through workgroup memory, so that a
// row's passes run in parallel rather than one invocation walking 300 rows' thousands of columns while the
// GPU idles. `row_stats` writes a row's statistics only (x0, delta, rstd, 0: a vec4 per row), which
// matmul.wgsl's `linear_tiled` reads to normalise its rows as it stages them (a transformer's pre-norm, the
// normalised rows never written).
//
// Three passes over the row (sum, sum of squared deviations, output), vec4 loads.
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

// A row's statistics as the single-invocation kernel takes them: its first element, the mean of the
// deviations from it, and 1 / std.
struct RowStats {
    x0: f32,
    delta: f32,
    rstd: f32,
}

// Row r's statistics (the workgroup's row: uniform across it), invocation lid taking vec4s lid, lid + 64, ...
fn wide_stats(r: u32, lid: u32) -> RowStats {
    let row = r * p.ld4;
    let lanes = vec4<u32>(0u, 1u, 2u, 3u);
    let x0 = x[row].x;
    var s = vec4<f32>(0.0);
    for (var k = lid; 4u * k < p.cols; k += WIDE) {
        s += select(vec4<f32>(0.0), x[row + k] - x0, vec4<u32>(4u * k) + lanes < vec4<u32>(p.cols));
    }
    let delta = workgroup_reduce(lid, (s.x + s.y) + (s.z + s.w), REDUCE_SUM) / f32(p.cols);
    var v = vec4<f32>(0.0);
    for (var k = lid; 4u * k < p.cols; k += WIDE) {
        let d = select(vec4<f32>(0.0), (x[row + k] - x0) - delta, vec4<u32>(4u * k) + lanes < vec4<u32>(p.cols));
        v += d * d;
    }
    let rstd = 1.0 / sqrt(workgroup_reduce(lid, (v.x + v.y) + (v.z + v.w), REDUCE_SUM) / f32(p.cols) + p.eps);
    return RowStats(x0, delta, rstd);
}

// The row of a workgroup-per-row entry, or p.rows past the last (the grid may have more groups).
fn wide_row(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return min(wid.x + wid.y * nwg.x, p.rows);
}

@compute @workgroup_size(64)
fn layernorm_wide(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let r = wide_row(wid, nwg);
    if (r == p.rows) {
        return; // the whole workgroup
    }
    let n = wide_stats(r, lid);
    let row = r * p.ld4;
    let lanes = vec4<u32>(0u, 1u, 2u, 3u);
    // The row's vec4s, the padding columns of the last written as zeros (as `layernorm` writes them).
    for (var k = lid; 4u * k < p.cols; k += WIDE) {
        let y = ((x[row + k] - n.x0) - n.delta) * n.rstd * gamma[k] + beta[k];
        out[row + k] = select(vec4<f32>(0.0), y, vec4<u32>(4u * k) + lanes < vec4<u32>(p.cols));
    }
}

// Statistics only: out is [rows, 4], row r holding (x0, delta, rstd, 0). gamma and beta are not read (the
// wrapper binds x there).
@compute @workgroup_size(64)
fn row_stats(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    // In the layout, as the wrapper binds every entry point's four buffers.
    _ = gamma[0];
    _ = beta[0];
    let r = wide_row(wid, nwg);
    if (r == p.rows) {
        return; // the whole workgroup
    }
    let n = wide_stats(r, lid);
    if (lid == 0u) {
        out[r] = vec4<f32>(n.x0, n.delta, n.rstd, 0.0);
    }
}
