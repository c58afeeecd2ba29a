//! Every WGSL file parses and validates with naga, independent of any adapter, and so do the variants
//! made from them (f16 weights), and the generated ones are current.

/// Each shader validates with the capabilities of its features and naga writes its SPIR-V (what wgpu hands a
/// Vulkan driver): the writer can panic on a module that validates (naga 30 on a cooperative-matrix pointer
/// indexed inline, issue 42), which matters most for the shaders no adapter here runs (`matmul_coop`).
#[test]
fn all_shaders_validate() {
    let kernels = raypatch_engine::kernels::ALL_SHADERS.iter().chain(&raypatch_engine::kernels::VARIANTS);
    for shader in kernels {
        let name = format!("{}.wgsl", shader.name);
        let (module, info) = crate::common::validate_wgsl(&name, &shader.wgsl(), shader.features);
        // The override constants at their defaults, as a pipeline without constants gets them.
        let (module, info) =
            naga::back::pipeline_constants::process_overrides(&module, &info, None, &Default::default())
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        // wgpu's Vulkan backend's options for a module with its default runtime checks.
        let restrict = naga::proc::BoundsCheckPolicy::Restrict;
        let bounds_check_policies =
            naga::proc::BoundsCheckPolicies { index: restrict, buffer: restrict, ..Default::default() };
        let options = naga::back::spv::Options { lang_version: (1, 3), bounds_check_policies, ..Default::default() };
        let written = std::panic::catch_unwind(|| naga::back::spv::write_vec(&module, &info, &options, None));
        match written {
            Ok(Ok(words)) => assert!(!words.is_empty(), "{name}: empty SPIR-V"),
            Ok(Err(e)) => panic!("{name}: naga's SPIR-V writer: {e}"),
            Err(_) => panic!("{name}: naga's SPIR-V writer panicked (above)"),
        }
    }
}

/// The generated shaders are what their scripts write from the wrappers' sizes: `shaders/matmul_lanes.wgsl`
/// (`tools/codegen/gen_matmul_lanes.py`), `shaders/tiles.wgsl` and the tiled GEMMs' register blocks
/// (`gen_tiles.py`), flash attention's registers (`gen_attention.py`). Needs python3
/// (any version, no packages): a machine without it fails here, saying so, rather than skip the check.
#[test]
fn generated_shaders_are_current() {
    for script in ["gen_matmul_lanes.py", "gen_tiles.py", "gen_attention.py"] {
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

/// The tiled GEMMs' sums are named variables, never an array: on NVIDIA's Vulkan driver one loop over them (the
/// stores of an earlier `linear_tiled`) put them in memory, 13x slower on an H200, and an array copied for the
/// stores' loop halved the split 300x1536x1536 on an H100 (docs/PERFORMANCE.md).
#[test]
fn tiled_sums_are_named_variables() {
    for shader in [&raypatch_engine::kernels::MATMUL, &raypatch_engine::kernels::CONV] {
        let source = shader.wgsl();
        // An array of sums, or any index into one, sends the block to memory on NVIDIA (tools/codegen/gen_tiles.py).
        assert!(!source.contains("sums["), "{}: the sums are indexed", shader.name);
        assert!(source.contains("var sums_0 = vec4<f32>(0.0);"), "{}: no named sums", shader.name);
    }
}

/// Every shader and variant has its own name: pipelines are cached by (name, entry point), so two sources under
/// one name would run each other's code.
#[test]
fn shader_names_are_unique() {
    let mut names: Vec<&str> = raypatch_engine::kernels::ALL_SHADERS
        .iter()
        .chain(&raypatch_engine::kernels::VARIANTS)
        .map(|s| s.name)
        .collect();
    names.sort_unstable();
    let repeated: Vec<_> = names.windows(2).filter(|pair| pair[0] == pair[1]).map(|pair| pair[0]).collect();
    assert!(repeated.is_empty(), "shader names used twice: {repeated:?}");
}
