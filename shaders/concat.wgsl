// Column concatenation: out[r, :] = cat(a[r, :], b[r, :]) for a [rows, a_cols] and b [rows, b_cols] (rows
// a_ld and b_ld floats apart), out [rows, a_cols + b_cols] with out_ld floats per row, zero padding. PyTorch's
// torch.cat(..., -1). One invocation per element of out, padding included.

struct Params {
    rows: u32,
    a_cols: u32,
    a_ld: u32,
    b_cols: u32,
    b_ld: u32,
    out_ld: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(64)
fn concat_columns(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (index >= p.rows * p.out_ld) {
        return;
    }
    let r = index / p.out_ld;
    let j = index % p.out_ld;
    var v = 0.0;
    if (j < p.a_cols) {
        v = a[r * p.a_ld + j];
    } else if (j < p.a_cols + p.b_cols) {
        v = b[r * p.b_ld + j - p.a_cols];
    }
    out[index] = v;
}
