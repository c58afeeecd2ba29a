// Elementwise column map: out[r, j] = f(x[r, col + j]) for j < cols(out), zero in out's row padding.
// One invocation per vec4 of out. `sigmoid` comes from the activation prelude (kernels/mod.rs).

// The codes of `Params.f`: their values are kernels::elementwise::Map's, which tests/uniforms.rs checks
// against these. Identity copies a channel range; the last two are DeFiNe's depth and log-depth.
const MAP_IDENTITY: u32 = 0u;
const MAP_SIGMOID: u32 = 1u;
const MAP_EXP: u32 = 2u;
// sigmoid(x)·scale + offset
const MAP_SIGMOID_AFFINE: u32 = 3u;
// log(sigmoid(x)·scale + offset)
const MAP_LOG_SIGMOID_AFFINE: u32 = 4u;

struct Params {
    rows: u32,
    // x's row stride in floats.
    x_ld: u32,
    // First column of x read.
    col: u32,
    // out's columns and row stride in vec4s.
    cols: u32,
    ld4: u32,
    f: u32,
    scale: f32,
    offset: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn map_columns(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let idx = (wid.x + wid.y * nwg.x) * 64u + lid;
    if (idx >= p.rows * p.ld4) {
        return;
    }
    let r = idx / p.ld4;
    let j = (idx % p.ld4) * 4u + vec4<u32>(0u, 1u, 2u, 3u);
    let valid = j < vec4<u32>(p.cols);
    // Padding lanes read the row's last column instead, to stay inside x's row.
    let at = r * p.x_ld + p.col + min(j, vec4<u32>(p.cols - 1u));
    var v = vec4<f32>(x[at.x], x[at.y], x[at.z], x[at.w]);
    if (p.f == MAP_SIGMOID) {
        v = sigmoid(v);
    } else if (p.f == MAP_EXP) {
        v = exp(v);
    } else if (p.f == MAP_SIGMOID_AFFINE || p.f == MAP_LOG_SIGMOID_AFFINE) {
        v = sigmoid(v) * p.scale + p.offset;
        if (p.f == MAP_LOG_SIGMOID_AFFINE) {
            v = log(v);
        }
    }
    out[idx] = select(vec4<f32>(0.0), v, valid);
}
