//! Every WGSL file parses and validates with naga, independent of any adapter, and so do the variants
//! made from them (f16 weights), and the generated ones are current.

#[test]
fn all_shaders_validate() {
    let kernels = raypatch_engine::kernels::ALL_SHADERS.iter().chain(&raypatch_engine::kernels::VARIANTS);
    for shader in kernels {
        crate::common::validate_wgsl(&format!("{}.wgsl", shader.name), &shader.wgsl(), shader.features);
    }
}

/// The generated shaders are what their scripts write from the wrappers' sizes: `shaders/matmul_lanes.wgsl`
/// (`tools/codegen/gen_matmul_lanes.py`) and `shaders/tiles.wgsl` (`tools/codegen/gen_tiles.py`). Needs python3
/// (any version, no packages): a machine without it fails here, saying so, rather than skip the check.
#[test]
fn generated_shaders_are_current() {
    for script in ["gen_matmul_lanes.py", "gen_tiles.py"] {
        let path = format!("{}/tools/codegen/{script}", env!("CARGO_MANIFEST_DIR"));
        let out = std::process::Command::new("python3").arg(&path).arg("--check").output().unwrap_or_else(|e| {
            panic!("python3 cannot be run ({e}): the shader tools/codegen/{script} writes cannot be checked")
        });
        assert!(
            out.status.success(),
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// The tiled GEMMs' sums are only ever indexed by constants: on NVIDIA's Vulkan driver one loop over them (the
/// stores of an earlier `linear_tiled`) put them in memory, 13x slower on an H200 (docs/PERFORMANCE.md).
#[test]
fn tiled_sums_are_indexed_by_constants_only() {
    for shader in [&raypatch_engine::kernels::MATMUL, &raypatch_engine::kernels::CONV] {
        let source = shader.wgsl();
        let mut uses = 0;
        for (at, _) in source.match_indices("sums[") {
            let index = &source[at + 5..];
            let digits = index.bytes().take_while(u8::is_ascii_digit).count();
            assert!(digits > 0 && index.as_bytes()[digits] == b']', "{}: sums[{}", shader.name, &index[..20]);
            uses += 1;
        }
        assert!(uses > 0, "{}: no `sums[` found", shader.name);
    }
}
