//! Every WGSL file parses and validates with naga, independent of any adapter, and so do the variants
//! made from them (f16 weights).

#[test]
fn all_shaders_validate() {
    let kernels = raypatch_engine::kernels::ALL_SHADERS.iter().chain(&raypatch_engine::kernels::VARIANTS);
    for shader in kernels {
        let source = shader.wgsl();
        let module = naga::front::wgsl::parse_str(&source)
            .unwrap_or_else(|e| panic!("{}.wgsl: {}", shader.name, e.emit_to_string(&source)));
        let capabilities = if shader.features.contains(raypatch_engine::wgpu::Features::SHADER_F16) {
            naga::valid::Capabilities::SHADER_FLOAT16
        } else {
            naga::valid::Capabilities::empty()
        };
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities)
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}.wgsl: {e:?}", shader.name));
    }
}
