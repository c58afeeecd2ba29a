//! Every WGSL file parses and validates with naga, independent of any adapter, and so do the variants
//! made from them (f16 weights), and the generated ones are current.

#[test]
fn all_shaders_validate() {
    let kernels = raypatch_engine::kernels::ALL_SHADERS.iter().chain(&raypatch_engine::kernels::VARIANTS);
    for shader in kernels {
        crate::common::validate_wgsl(&format!("{}.wgsl", shader.name), &shader.wgsl(), shader.features);
    }
}

/// `shaders/matmul_lanes.wgsl` is what `tools/gen_matmul_lanes.py` writes (skipped without python3).
#[test]
fn generated_shaders_are_current() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/gen_matmul_lanes.py");
    match std::process::Command::new("python3").arg(root).arg("--check").output() {
        Ok(out) => assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stdout)),
        Err(e) => eprintln!("python3 not found ({e}): generated shaders not checked"),
    }
}
