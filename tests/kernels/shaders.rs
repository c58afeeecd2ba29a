//! Every WGSL file parses and validates with naga, independent of any adapter.

#[test]
fn all_shaders_validate() {
    for shader in raypatch_engine::kernels::ALL_SHADERS {
        let module = naga::front::wgsl::parse_str(shader.source)
            .unwrap_or_else(|e| panic!("{}.wgsl: {}", shader.name, e.emit_to_string(shader.source)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty())
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}.wgsl: {e:?}", shader.name));
    }
}
