//! Every kernel's uniform is declared twice: `struct Params` in its WGSL and a `#[repr(C)]` struct in its
//! Rust wrapper (`kernels::params!`). The shader reads the bytes the wrapper writes, so the two must agree
//! on every member's name, offset and type and on the size; a reordered, renamed or retyped field on
//! either side fails here, without a GPU. The shaders are the ones the engine compiles (variants included),
//! from its one list, `kernels::UNIFORMS`.

mod common;

use naga::{ArraySize, Handle, Module, ScalarKind, Type, TypeInner, VectorSize};
use raypatch_engine::kernels::{Field, ParamsLayout, ALL_SHADERS, UNIFORMS, VARIANTS};
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
