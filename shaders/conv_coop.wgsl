// `conv_coop` (MatmulKernel::Coop): conv.wgsl's convolution as an implicit GEMM on coop_tiles.wgsl's
// cooperative-matrix GEMM, as `conv_tiled` is on tiles.wgsl: M = output pixels, N = output channels, K = the
// weight row (taps x cin4 vec4s, tap-major, walked whatever the tap boundaries). It comes after coop_tiles.wgsl in
// its shader and before activation.wgsl, tiles.wgsl and conv.wgsl, whose Params, bindings, im2col gather
// (`window_of`, `gather`: zero padding and the 2x nearest upsampling resolved per load) and split-K epilogue
// (`store_sum`, `conv_reduce`) it shares.

fn coop_m() -> u32 { return p.npix; }
fn coop_n() -> u32 { return p.cout; }
fn coop_k4() -> u32 { return p.k * p.k * p.cin4; }
fn coop_splits() -> u32 { return p.splits; }
fn coop_k_split4() -> u32 { return p.k_split4; }

fn coop_a4(row: u32, k4: u32) -> vec4<f32> {
    return gather(window_of(row), k4);
}

fn coop_b4(col: u32, k4: u32) -> vec4<f32> {
    return w[col * coop_k4() + k4];
}

@compute @workgroup_size(COOP_WG)
fn conv_coop(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) li: u32, @builtin(subgroup_id) sg: u32,
             @builtin(subgroup_invocation_id) lane: u32) {
    coop_gemm(wid.x + wid.y * nwg.x, li, sg, lane);
}
