//! Every kernel's uniform is declared twice: `struct Params` in its WGSL and a `#[repr(C)]` struct in its
//! Rust wrapper (`kernels::params!`). The shader reads the bytes the wrapper writes, so the two must agree
//! on every member's name, offset and type and on the size; a reordered, renamed or retyped field on
//! either side fails here, without a GPU. The shaders are the ones the engine compiles (variants included),
//! from its one list, `kernels::UNIFORMS`. The codes the kernels read from those fields (activations, modes,
//! maps, ray kinds) are named WGSL constants whose values must be the wrappers' (`kernels::shader_codes`).

mod common;

use naga::{ArraySize, Handle, Module, ScalarKind, Type, TypeInner, VectorSize};
use raypatch_engine::kernels::{shader_codes, Field, ParamsLayout, ShaderCode, ALL_SHADERS, UNIFORMS, VARIANTS};
use raypatch_engine::wgpu::Features;

/// A naga type as the Rust type that has its layout in a uniform, and that type's size:
/// `u32`, `f32`, `i32`, `[f32; 4]` for a vec4, `[[f32; 4]; 8]` for an array of them.
fn rust_type(module: &Module, ty: Handle<Type>, what: &str) -> (String, u32) {
    match module.types[ty].inner {
        TypeInner::Scalar(scalar) if scalar.width == 4 => {
            let name = match scalar.kind {
                ScalarKind::Uint => "u32",
                ScalarKind::Sint => "i32",
                ScalarKind::Float => "f32",
                other => panic!("{what}: scalar kind {other:?} has no Rust counterpart here"),
            };
            (name.to_string(), 4)
        }
        TypeInner::Vector { size, scalar } if scalar.width == 4 => {
            let n = match size {
                VectorSize::Bi => 2,
                VectorSize::Tri => 3,
                VectorSize::Quad => 4,
            };
            let (elem, _) = rust_type_of_scalar(scalar.kind, what);
            (format!("[{elem}; {n}]"), 4 * n)
        }
        TypeInner::Array { base, size: ArraySize::Constant(n), stride } => {
            let (elem, elem_size) = rust_type(module, base, what);
            // A Rust array packs its elements; a uniform array whose stride differs (array<f32> has a
            // 16-byte stride in a uniform) cannot be mirrored by one.
            assert_eq!(stride, elem_size, "{what}: array stride {stride} is not its element's size {elem_size}");
            (format!("[{elem}; {n}]"), elem_size * n.get())
        }
        ref other => panic!("{what}: type {other:?} has no Rust counterpart here"),
    }
}

fn rust_type_of_scalar(kind: ScalarKind, what: &str) -> (&'static str, u32) {
    match kind {
        ScalarKind::Uint => ("u32", 4),
        ScalarKind::Sint => ("i32", 4),
        ScalarKind::Float => ("f32", 4),
        other => panic!("{what}: scalar kind {other:?} has no Rust counterpart here"),
    }
}

/// The struct bound as a uniform at group 0, binding 0 of `source`: its name, members (as Rust would
/// write them) and size. Checks that every entry point reads it.
fn params_struct(name: &str, source: &str, features: Features) -> (String, Vec<Field>, usize) {
    let (module, info) = common::validate_wgsl(name, source, features);

    let bound: Vec<_> = module
        .global_variables
        .iter()
        .filter(|(_, var)| var.binding.as_ref().is_some_and(|b| b.group == 0 && b.binding == 0))
        .collect();
    assert_eq!(bound.len(), 1, "{name}: expected one variable at @group(0) @binding(0)");
    let (handle, var) = bound[0];
    assert_eq!(var.space, naga::AddressSpace::Uniform, "{name}: binding 0 must be the params uniform");
    assert!(!module.entry_points.is_empty(), "{name}: no entry points");
    for (i, entry) in module.entry_points.iter().enumerate() {
        assert!(!info.get_entry_point(i)[handle].is_empty(), "{name}: entry point {} ignores its params", entry.name);
    }

    let ty = &module.types[var.ty];
    let TypeInner::Struct { ref members, span } = ty.inner else {
        panic!("{name}: the params uniform is not a struct");
    };
    let fields = members
        .iter()
        .map(|m| {
            let field = m.name.clone().unwrap_or_default();
            let (rust, _) = rust_type(&module, m.ty, &format!("{name}: Params.{field}"));
            Field { name: Box::leak(field.into_boxed_str()), offset: m.offset as usize, ty: Box::leak(rust.into()) }
        })
        .collect();
    (ty.name.clone().unwrap_or_default(), fields, span as usize)
}

/// One line per field, for a readable diff when the sides disagree.
fn describe(fields: &[Field]) -> String {
    fields.iter().map(|f| format!("  {:>3}  {}: {}\n", f.offset, f.name, f.ty)).collect()
}

/// Compares a shader's `Params` with the Rust struct: `Err` with both layouts when they differ.
fn compare(name: &str, source: &str, features: Features, rust: &ParamsLayout) -> Result<(), String> {
    let (wgsl_name, wgsl_fields, wgsl_size) = params_struct(name, source, features);
    if wgsl_name != "Params" {
        return Err(format!("{name}: the uniform struct is named {wgsl_name}, not Params"));
    }
    if wgsl_fields != rust.fields || wgsl_size != rust.size {
        return Err(format!(
            "{name}.wgsl's Params ({wgsl_size} bytes) and the Rust {} ({} bytes) disagree:\nWGSL:\n{}Rust:\n{}",
            rust.name,
            rust.size,
            describe(&wgsl_fields),
            describe(rust.fields)
        ));
    }
    Ok(())
}

#[test]
fn every_shader_params_matches_its_rust_struct() {
    let mismatches: Vec<String> = UNIFORMS
        .iter()
        .filter_map(|(shader, rust)| compare(shader.name, &shader.wgsl(), shader.features, rust).err())
        .collect();
    assert!(mismatches.is_empty(), "{}", mismatches.join("\n"));
}

/// The uniform list covers every shader the engine compiles, each once.
#[test]
fn uniform_list_covers_every_shader() {
    let listed: Vec<&str> = UNIFORMS.iter().map(|(s, _)| s.name).collect();
    let compiled: Vec<&str> = ALL_SHADERS.iter().chain(&VARIANTS).map(|s| s.name).collect();
    assert_eq!(listed, compiled);
}

/// The comparison itself: a renamed, reordered, retyped or added member on the WGSL side is caught (the
/// Rust side is compared the same way, from the `offset_of!` offsets of its fields).
#[test]
fn a_mismatch_is_caught() {
    let (shader, rust) = UNIFORMS.iter().find(|(s, _)| s.name == "layernorm").expect("layernorm");
    let source = shader.wgsl();
    compare(shader.name, &source, shader.features, rust).expect("layernorm as it is");
    // (struct edit, body edit keeping the kernel valid WGSL)
    let edits = [
        (("    cols: u32,\n", "    columns: u32,\n"), ("p.cols", "p.columns")),
        (("    rows: u32,\n    cols: u32,\n", "    cols: u32,\n    rows: u32,\n"), ("", "")),
        (("    eps: f32,\n", "    eps: u32,\n"), ("p.eps", "f32(p.eps)")),
        (("    eps: f32,\n", "    eps: f32,\n    extra: u32,\n"), ("", "")),
        (("struct Params {", "struct Uniforms {"), ("var<uniform> p: Params", "var<uniform> p: Uniforms")),
    ];
    for ((from, to), (body_from, body_to)) in edits {
        assert_eq!(source.matches(from).count(), 1, "`{from}` should occur once in layernorm.wgsl");
        let mut edited = source.replacen(from, to, 1);
        if !body_from.is_empty() {
            edited = edited.replace(body_from, body_to);
        }
        let result = compare(shader.name, &edited, shader.features, rust);
        assert!(result.is_err(), "editing `{from}` into `{to}` went unnoticed");
    }
}

/// The named constants of a shader's source, with their values.
fn wgsl_constants(name: &str, source: &str, features: Features) -> Vec<(String, f64)> {
    let (module, _) = common::validate_wgsl(name, source, features);
    module
        .constants
        .iter()
        .filter_map(|(_, c)| {
            let value = match module.global_expressions[c.init] {
                naga::Expression::Literal(naga::Literal::U32(v)) => v as f64,
                naga::Expression::Literal(naga::Literal::I32(v)) => v as f64,
                naga::Expression::Literal(naga::Literal::F32(v)) => v as f64,
                _ => return None,
            };
            Some((c.name.clone()?, value))
        })
        .collect()
}

/// Where the shaders' code constants and the wrappers' codes disagree: a value that differs, a code the shader
/// does not declare, or a constant of a code family (its prefix) that no wrapper value stands for.
fn code_mismatches(codes: &[ShaderCode], source_of: impl Fn(&str) -> String) -> Vec<String> {
    let family = |name: &str| name.split('_').next().unwrap_or_default().to_string();
    let families: std::collections::BTreeSet<String> = codes.iter().map(|c| family(c.name)).collect();
    let shaders: std::collections::BTreeSet<&str> = codes.iter().map(|c| c.shader).collect();
    let mut mismatches = Vec::new();
    for shader in shaders {
        let features = ALL_SHADERS.iter().find(|s| s.name == shader).expect("a listed shader").features;
        let constants = wgsl_constants(shader, &source_of(shader), features);
        for code in codes.iter().filter(|c| c.shader == shader) {
            match constants.iter().find(|(name, _)| name == code.name) {
                Some((_, value)) if *value == code.value => {}
                Some((_, value)) => {
                    mismatches.push(format!("{shader}: {} is {value} in WGSL, {} in Rust", code.name, code.value))
                }
                None => mismatches.push(format!("{shader}: no WGSL constant {} (Rust code {})", code.name, code.value)),
            }
        }
        for (name, _) in &constants {
            let listed = codes.iter().any(|c| c.shader == shader && c.name == name);
            if families.contains(&family(name)) && name.contains('_') && !listed {
                mismatches.push(format!("{shader}: WGSL constant {name} stands for no Rust code"));
            }
        }
    }
    mismatches
}

fn shader_source(name: &str) -> String {
    ALL_SHADERS.iter().find(|s| s.name == name).expect("a listed shader").wgsl().into_owned()
}

#[test]
fn every_code_a_kernel_reads_has_the_wrappers_value_in_its_shader() {
    let codes = shader_codes();
    assert!(codes.len() >= 14, "activations, modes, maps and ray kinds: {codes:?}");
    let mismatches = code_mismatches(&codes, shader_source);
    assert!(mismatches.is_empty(), "{}", mismatches.join("\n"));
}

/// The comparison itself: a changed value, a renamed constant and an extra constant of a family are caught.
#[test]
fn a_code_mismatch_is_caught() {
    let codes = shader_codes();
    let edits = [
        ("elementwise", "const ACT_GELU: u32 = 3u;", "const ACT_GELU: u32 = 4u;"),
        ("elementwise", "const MAP_IDENTITY: u32 = 0u;", "const MAP_COPY: u32 = 0u;"),
        (
            "elementwise",
            "const MODE_RESIDUAL: u32 = 2u;",
            "const MODE_RESIDUAL: u32 = 2u;\nconst MODE_SCALED: u32 = 3u;",
        ),
        ("rays", "const RAY_KIND_UNIT_DEPTH_POINT: f32 = 1.0;", "const RAY_KIND_UNIT_DEPTH_POINT: f32 = 2.0;"),
    ];
    for (shader, from, to) in edits {
        let source = shader_source(shader);
        assert_eq!(source.matches(from).count(), 1, "`{from}` should occur once in {shader}");
        let edited = |name: &str| if name == shader { source.replacen(from, to, 1) } else { shader_source(name) };
        assert!(!code_mismatches(&codes, edited).is_empty(), "editing `{from}` into `{to}` went unnoticed");
    }
}
