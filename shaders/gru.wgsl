// PyTorch's nn.GRUCell from its two gate projections: gi = x·W_ihᵀ + b_ih and gh = h·W_hhᵀ + b_hh, each
// [rows, 3·dim] with the gates in PyTorch's order r, z, n (rows gates_ld floats apart), and h [rows, dim]:
//   r = σ(gi_r + gh_r), z = σ(gi_z + gh_z), n = tanh(gi_n + r·gh_n), h' = (h - n)·z + n
// (h' = (1 - z)·n + z·h written as ATen's CPU GRUCell evaluates it). out [rows, dim], ld floats per row of h
// and out, zero padding. One invocation per element of out, padding included. `sigmoid` and `tanh_stable`
// come from the activation prelude.

struct Params {
    rows: u32,
    dim: u32,
    // floats per row of gi and gh.
    gates_ld: u32,
    // floats per row of h and out.
    ld: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> gi: array<f32>;
@group(0) @binding(2) var<storage, read> gh: array<f32>;
@group(0) @binding(3) var<storage, read> h: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(64)
fn gru_cell(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) lid: u32) {
    let index = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (index >= p.rows * p.ld) {
        return;
    }
    let row = index / p.ld;
    let j = index % p.ld;
    if (j >= p.dim) {
        out[index] = 0.0;
        return;
    }
    let g = row * p.gates_ld + j;
    let r = sigmoid(vec4<f32>(gi[g] + gh[g])).x;
    let z = sigmoid(vec4<f32>(gi[g + p.dim] + gh[g + p.dim])).x;
    let n = tanh_stable(vec4<f32>(gi[g + 2u * p.dim] + r * gh[g + 2u * p.dim])).x;
    let prev = h[row * p.ld + j];
    out[index] = (prev - n) * z + n;
}
