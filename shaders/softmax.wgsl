// Softmax and normalisation along one axis of x [rows, cols] (row stride ld floats), into out of the same shape:
// - softmax_rows:    out[r, :] = softmax(scale · x[r, :]) + eps, one invocation per row (CPU adapters), or
//   softmax_rows_wide, a workgroup per row (GPUs, device::reduce_rows_per_workgroup: DeFiNe's 1200 x 2048
//   attention weights, one invocation walking each row, took 1.1 ms of an H200);
// - softmax_columns: out[:, c] = softmax(scale · x[:, c]) + eps, one invocation per column of ld (columns past
//   cols write the zero padding);
// - normalize_rows:  out[r, :] = x[r, :] / Σ x[r, :], one invocation per row.
// Softmax subtracts the maximum before exp, as PyTorch does: the scaled logits are rounded to f32 first
// ((q·k)·scale is how the official modules write it), then exp(v - max) / Σ exp(v - max), then + eps.
// These axes are short (slots: 4-32; inputs of slot attention: a few hundred), so each invocation walks its own.

struct Params {
    rows: u32,
    cols: u32,
    // floats per row of x and out.
    ld: u32,
    scale: f32,
    eps: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

fn flat_index(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> u32 {
    return (wid.x + wid.y * nwg.x) * 64u + lid;
}

// Softmax of the `len` elements first, first + stride, ... into out.
fn softmax(first: u32, stride: u32, len: u32) {
    var m = x[first] * p.scale;
    for (var i = 1u; i < len; i++) {
        m = max(m, x[first + i * stride] * p.scale);
    }
    var sum = 0.0;
    for (var i = 0u; i < len; i++) {
        sum += exp(x[first + i * stride] * p.scale - m);
    }
    for (var i = 0u; i < len; i++) {
        let at = first + i * stride;
        out[at] = exp(x[at] * p.scale - m) / sum + p.eps;
    }
}

fn zero_row_padding(r: u32) {
    for (var j = p.cols; j < p.ld; j++) {
        out[r * p.ld + j] = 0.0;
    }
}

@compute @workgroup_size(64)
fn softmax_rows(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let r = flat_index(wid, nwg, lid);
    if (r >= p.rows) {
        return;
    }
    softmax(r * p.ld, 1u, p.cols);
    zero_row_padding(r);
}

@compute @workgroup_size(64)
fn softmax_columns(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) lid: u32) {
    let c = flat_index(wid, nwg, lid);
    if (c >= p.ld) {
        return;
    }
    if (c >= p.cols) {
        for (var r = 0u; r < p.rows; r++) {
            out[r * p.ld + c] = 0.0;
        }
        return;
    }
    softmax(c, p.ld, p.rows);
}

@compute @workgroup_size(64)
fn normalize_rows(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) lid: u32) {
    let r = flat_index(wid, nwg, lid);
    if (r >= p.rows) {
        return;
    }
    var sum = 0.0;
    for (var j = 0u; j < p.cols; j++) {
        sum += x[r * p.ld + j];
    }
    for (var j = 0u; j < p.cols; j++) {
        out[r * p.ld + j] = x[r * p.ld + j] / sum;
    }
    zero_row_padding(r);
}

// softmax_rows_wide: a workgroup per row, invocation lid taking columns lid, lid + 64, ...; the row's max and
// sum through workgroup memory (row_reduce.wgsl). The same formula as `softmax`: exp(scale·x - max) / Σ, then
// + eps.
@compute @workgroup_size(64)
fn softmax_rows_wide(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                     @builtin(local_invocation_index) lid: u32) {
    let r = wid.x + wid.y * nwg.x;
    if (r >= p.rows) {
        return; // the whole workgroup
    }
    let first = r * p.ld;
    var m = -3.0e38;
    for (var j = lid; j < p.cols; j += WIDE) {
        m = max(m, x[first + j] * p.scale);
    }
    m = workgroup_reduce(lid, m, REDUCE_MAX);
    var sum = 0.0;
    for (var j = lid; j < p.cols; j += WIDE) {
        sum += exp(x[first + j] * p.scale - m);
    }
    sum = workgroup_reduce(lid, sum, REDUCE_SUM);
    for (var j = lid; j < p.ld; j += WIDE) {
        var v = 0.0;
        if (j < p.cols) {
            v = exp(x[first + j] * p.scale - m) / sum + p.eps;
        }
        out[first + j] = v;
    }
}
