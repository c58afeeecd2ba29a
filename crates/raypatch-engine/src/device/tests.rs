//! Where the tensor kernels run, their tilings, and the choice at a precision.

use super::*;

fn adapter(name: &str, lanes: (u32, u32)) -> wgpu::AdapterInfo {
    wgpu::AdapterInfo {
        name: name.into(),
        subgroup_min_size: lanes.0,
        subgroup_max_size: lanes.1,
        ..wgpu::AdapterInfo::new(wgpu::DeviceType::Cpu, wgpu::Backend::Vulkan)
    }
}

fn configuration(tile: u32, cr: wgpu::CooperativeScalarType) -> wgpu::CooperativeMatrixProperties {
    let f16 = wgpu::CooperativeScalarType::F16;
    let (m_size, n_size, k_size) = (tile, tile, tile);
    wgpu::CooperativeMatrixProperties {
        m_size,
        n_size,
        k_size,
        ab_type: f16,
        cr_type: cr,
        saturating_accumulation: false,
    }
}

const ALL: wgpu::Features = COOP_FEATURES;
const F32: wgpu::CooperativeScalarType = wgpu::CooperativeScalarType::F32;

/// An adapter's limits with 48 KiB of workgroup memory (NVIDIA's; lavapipe's is more).
fn limits() -> wgpu::Limits {
    wgpu::Limits { max_compute_workgroup_storage_size: 48 << 10, ..Default::default() }
}

#[test]
fn the_tensor_kernels_take_the_adapters_tile_and_subgroups_where_they_fit() {
    let limits = limits();
    let lavapipe = adapter("llvmpipe (LLVM 19.1.7, 256 bits)", (8, 8));
    let shape = CoopShape::of_adapter(&lavapipe, ALL, &[configuration(8, F32)], &limits).unwrap();
    assert_eq!(
        (shape.tile, shape.lanes, shape.tile_rows(shape.tiling(1)), shape.tile_cols(shape.tiling(1))),
        (8, 8, 32, 32)
    );
    let nvidia = adapter("NVIDIA H100", (32, 32));
    let both = [configuration(8, F32), configuration(16, F32)];
    assert_eq!(CoopShape::of_adapter(&nvidia, ALL, &both, &limits).unwrap().tile, 16);
    let refused = [
        // llvmpipe without AVX2: the feature listed, 4-lane subgroups; making the device would panic.
        (adapter("llvmpipe (LLVM 19.1.7, 128 bits)", (4, 4)), ALL, vec![configuration(8, F32)]),
        (adapter("llvmpipe (LLVM 19.1.7, 128 bits)", (8, 8)), ALL, vec![configuration(8, F32)]),
        (adapter("Intel Arc", (8, 32)), ALL, vec![configuration(16, F32)]),
        (nvidia.clone(), ALL, vec![configuration(16, wgpu::CooperativeScalarType::F16)]),
        (nvidia.clone(), ALL - wgpu::Features::SHADER_F16, vec![configuration(16, F32)]),
        (nvidia.clone(), ALL - wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX, vec![configuration(16, F32)]),
    ];
    for (info, features, configurations) in refused {
        assert!(CoopShape::of_adapter(&info, features, &configurations, &limits).is_err(), "{info:?}");
    }
    // WebGPU's default 16 KiB of workgroup memory: one subgroup, K staged one tile a step.
    let small = CoopShape::of_adapter(&nvidia, ALL, &both, &wgpu::Limits::default()).unwrap();
    assert_eq!(small.tiling(1), CoopTiling { sg_m: 1, sg_n: 1, bk: 16 });
    assert_eq!(llvmpipe_bits("llvmpipe (LLVM 15.0.6, 256 bits)"), Some(256));
    assert_eq!(llvmpipe_bits("NVIDIA H100 80GB"), None);
}

#[test]
fn tuned_tilings_apply_to_their_adapter_and_class_where_they_fit() {
    let limits = limits();
    let info = adapter("NVIDIA H100", (32, 32));
    let shape = CoopShape::of_adapter(&info, ALL, &[configuration(16, F32)], &limits).unwrap();
    let tuning = "NVIDIA H100\tlarge\t4\t2\t32\nOther GPU\tsmall\t1\t1\t16\nNVIDIA H100\tsmall\t8\t8\t16\n\
                  NVIDIA H100\tsmall\tx\t1\t16\nNVIDIA H100\tsmall\t1\t1\t24\n";
    let tuned = shape.tuned(tuning, "NVIDIA H100", &limits);
    assert_eq!(tuned.tiling(GemmClass::LARGE_ROWS + 1), CoopTiling { sg_m: 4, sg_n: 2, bk: 32 });
    // The small class's lines: another adapter's, one too large for the limits, one unparsable, one whose K
    // step is not whole tiles: the default stays.
    assert_eq!(tuned.tiling(GemmClass::LARGE_ROWS), shape.tiling(1));
    assert_eq!(tuned.constants(tuned.tiling(5000))[1..], [("COOP_SG_M", 4.0), ("COOP_SG_N", 2.0), ("COOP_BK", 32.0)]);
}

#[test]
fn f16_activations_run_on_the_tensor_kernels_only_where_the_device_has_them() {
    let shape =
        CoopShape { tile: 8, lanes: 8, tilings: [CoopTiling { sg_m: 2, sg_n: 2, bk: 16 }; 2], workgroup_bytes: 32768 };
    let lanes = KernelChoice { matmul: MatmulKernel::Lanes, coop: Some(shape), ..Default::default() };
    assert_eq!(lanes.at_precision(true).matmul, MatmulKernel::Coop);
    assert_eq!(lanes.at_precision(false).matmul, MatmulKernel::Lanes);
    assert_eq!(KernelChoice { coop: None, ..lanes }.at_precision(true).matmul, MatmulKernel::Lanes);
    assert_eq!(KernelChoice { pinned: true, ..lanes }.at_precision(true).matmul, MatmulKernel::Lanes);
    // Heads whose tiles do not fit the workgroup memory run as on `Tiled`.
    let coop = lanes.at_precision(true);
    assert!(matches!(attention_variant(&coop, 10, 64, || None::<()>), AttentionVariant::Coop(_)));
    let small = KernelChoice { coop: Some(CoopShape { workgroup_bytes: 4096, ..shape }), ..coop };
    assert!(matches!(attention_variant(&small, 10, 64, || None::<()>), AttentionVariant::Flash { .. }));
}

/// SwiftShader's limits in Chromium (issue 49): a fallback adapter with 10 storage buffers per stage, 32 KiB of
/// workgroup memory, 256 invocations, no f16 and no subgroups.
fn swiftshader_limits() -> wgpu::Limits {
    wgpu::Limits {
        max_storage_buffers_per_shader_stage: 10,
        max_compute_workgroup_storage_size: 32 << 10,
        max_compute_invocations_per_workgroup: 256,
        ..wgpu::Limits::defaults()
    }
}

#[test]
fn kernels_are_chosen_within_the_adapters_limits() {
    let none = wgpu::Features::empty();
    let gpu = wgpu::AdapterInfo::new(wgpu::DeviceType::Other, wgpu::Backend::BrowserWebGpu);
    let fallback = wgpu::AdapterInfo::new(wgpu::DeviceType::Cpu, wgpu::Backend::BrowserWebGpu);
    let webgpu_minimum = wgpu::Limits::defaults();
    assert_eq!(check_limits(&swiftshader_limits()), Ok(()));
    assert_eq!(check_limits(&webgpu_minimum), Ok(()));
    assert_eq!(MatmulKernel::best_for(&fallback, none, &swiftshader_limits()), MatmulKernel::Rows);
    assert_eq!(MatmulKernel::best_for(&gpu, none, &webgpu_minimum), MatmulKernel::Tiled);
    let small = wgpu::Limits { max_compute_workgroup_storage_size: 8 << 10, ..webgpu_minimum.clone() };
    assert_eq!(MatmulKernel::best_for(&gpu, none, &small), MatmulKernel::Rows);
    let why = MatmulKernel::Tiled.fits(&small).unwrap_err();
    assert!(why.contains("maxComputeWorkgroupStorageSize is 8192"), "{why}");
    let few = wgpu::Limits { max_storage_buffers_per_shader_stage: 6, ..webgpu_minimum.clone() };
    let why = check_limits(&few).unwrap_err();
    assert!(why.contains("maxStorageBuffersPerShaderStage is 6"), "{why}");
    let narrow = wgpu::Limits { max_compute_invocations_per_workgroup: 32, ..webgpu_minimum };
    assert!(check_limits(&narrow).unwrap_err().contains("maxComputeInvocationsPerWorkgroup is 32"));
}

#[test]
fn no_shader_binds_more_storage_buffers_than_the_limit_the_engine_asks_for() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shaders");
    let mut most = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "wgsl") {
            // Every storage buffer a module declares (an entry point binds at most these).
            let count = std::fs::read_to_string(&path).unwrap().matches("var<storage").count() as u32;
            assert!(count <= STORAGE_BUFFERS_PER_STAGE, "{} declares {count} storage buffers", path.display());
            most = most.max(count);
        }
    }
    assert_eq!(most, STORAGE_BUFFERS_PER_STAGE, "the constant should be the most any shader binds");
}

#[test]
fn tiled_workgroup_memory_is_flash_attentions_tiles() {
    let flash = include_str!("../../../../shaders/attention_flash.wgsl");
    assert!(flash.contains("const TILE_VEC4S: u32 = 512u;"));
    assert_eq!(flash.matches("array<vec4<f32>, TILE_VEC4S>").count(), 2);
    assert_eq!(TILED_WORKGROUP_BYTES, 2 * 512 * 16);
}
