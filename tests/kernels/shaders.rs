//! Every WGSL file parses and validates with naga, independent of any adapter, and so do the variants
//! made from them (f16 weights), and the generated ones are current.

#[test]
fn all_shaders_validate() {
    let kernels = raypatch_engine::kernels::ALL_SHADERS.iter().chain(&raypatch_engine::kernels::VARIANTS);
    for shader in kernels {
        crate::common::validate_wgsl(&format!("{}.wgsl", shader.name), &shader.wgsl(), shader.features);
    }
}

/// `shaders/matmul_lanes.wgsl` is what `tools/codegen/gen_matmul_lanes.py` writes from the wrapper's sizes. Needs
/// python3 (any version, no packages): a machine without it fails here, saying so, rather than skip the check.
#[test]
fn generated_shaders_are_current() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/codegen/gen_matmul_lanes.py");
    let out = std::process::Command::new("python3").arg(root).arg("--check").output().unwrap_or_else(|e| {
        panic!("python3 cannot be run ({e}): shaders/matmul_lanes.wgsl cannot be checked against tools/codegen/gen_matmul_lanes.py")
    });
    assert!(out.status.success(), "{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
}
