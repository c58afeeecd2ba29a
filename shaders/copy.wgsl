// Copy into columns: out[r, col + j] = x[(first_row + r) / repeat, j] for j < cols, other columns of out
// untouched. `repeat` broadcasts one row of x (a view's camera position) over many rows of out. The DeFiNe
// tokens and queries, cat(features..., ray, camera position, encodings), are assembled from their parts this
// way. One invocation per copied element.

struct Params {
    // Rows of out written.
    rows: u32,
    // Columns copied (x's columns).
    cols: u32,
    // Floats per row of x.
    x_ld: u32,
    // Floats per row of out.
    out_ld: u32,
    // First column of out written.
    col: u32,
    // Rows of out per row of x, and the index of out's first row in that broadcast.
    repeat: u32,
    first_row: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(64)
fn copy_columns(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (index >= p.rows * p.cols) {
        return;
    }
    let r = index / p.cols;
    let j = index % p.cols;
    out[r * p.out_ld + p.col + j] = x[((p.first_row + r) / p.repeat) * p.x_ld + j];
}
