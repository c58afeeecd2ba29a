// `linear_coop` (MatmulKernel::Coop): matmul.wgsl's linear layer on coop_tiles.wgsl's cooperative-matrix GEMM. It
// comes after coop_tiles.wgsl in its shader and before activation.wgsl, tiles.wgsl and matmul.wgsl, whose Params,
// bindings 0-7, `op_*` accessors, the layer norm of x's rows as they are staged (`row_norm`, `x_staged`) and the
// split-K epilogue (`store_sum`, `linear_reduce`) it shares; WGSL's module-scope declarations may come in any
// order. The f16-weight variant replaces WeightVec as for `matmul_f16`.

fn coop_m() -> u32 { return op_m(); }
fn coop_n() -> u32 { return op_n(); }
fn coop_k4() -> u32 { return op_k4(); }
fn coop_splits() -> u32 { return op_splits(); }
fn coop_k_split4() -> u32 { return op_k_split4(); }

// Vec4 k4 of x's row, layer-normalised first where the layer asks (f32: the rounding to f16 comes after).
fn coop_a4(row: u32, k4: u32) -> vec4<f32> {
    return x_staged(row * op_k4(), k4, row_norm(row));
}

fn coop_b4(col: u32, k4: u32) -> vec4<f32> {
    return vec4<f32>(w[col * op_w_ld4() + k4]);
}

@compute @workgroup_size(COOP_WG)
fn linear_coop(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32, @builtin(subgroup_id) sg: u32,
               @builtin(subgroup_invocation_id) lane: u32) {
    coop_gemm(wid.x + wid.y * nwg.x, li, sg, lane);
}
