//! A pinhole camera's rays made on the GPU (`shaders/rays.wgsl`) from the host's column and row terms
//! (`raypatch_model::pinhole`): bit-equal to the rays the host makes for the same camera, of the camera's kind
//! (the terms carry it: `PinholeRays::gpu_kind`).

use super::RAYS;
use crate::error::Result;
use crate::gpu::Gpu;
use crate::plan::{grid, Access, Op, PlanBuilder, View};
use crate::tensor::padded_cols;
use raypatch_model::pinhole::{gpu_kind_of, Intrinsics, PinholeRays, TERM_FLOATS};
use raypatch_model::RayKind;

/// The `RAY_KIND_*` constant of `shaders/rays.wgsl` for a kind, and the value its terms carry
/// ([`super::ShaderCode`]).
pub(super) fn kind_constant(kind: RayKind) -> (&'static str, f64) {
    let name = match kind {
        RayKind::UnitDirection => "RAY_KIND_UNIT_DIRECTION",
        RayKind::UnitDepthPoint => "RAY_KIND_UNIT_DEPTH_POINT",
    };
    (name, gpu_kind_of(kind) as f64)
}

params! {
    /// The uniform of `shaders/rays.wgsl`.
    RaysParams {
        views: u32,
        height: u32,
        width: u32,
        terms_ld: u32,
        out_ld: u32,
        /// 0 (the shader's guard against rewrites of its error-free sums).
        zero: u32,
    }
}

/// Invocations per workgroup: one per ray.
const GROUP_SIZE: usize = 64;

/// The operands of [`pinhole_rays`].
#[derive(Clone, Copy, Debug)]
pub struct PinholeRaysArgs {
    /// `[views * (width + height), TERM_FLOATS]`: per view, the column terms, then the row terms.
    pub terms: View,
    pub views: usize,
    pub height: usize,
    pub width: usize,
    /// `[views * height * width, 3]`.
    pub out: View,
}

/// `out[(v * height + i) * width + j] = ray(column j + row i)`, the ray of the kind view v's terms carry.
pub fn pinhole_rays(plan: &mut PlanBuilder, label: &str, args: PinholeRaysArgs) {
    let PinholeRaysArgs { terms, views, height, width, out } = args;
    let rays = views * height * width;
    assert_eq!(terms.rows, views * (width + height), "pinhole_rays {label}: terms are not {views} views' terms");
    assert_eq!(plan.cols(terms.id), TERM_FLOATS, "pinhole_rays {label}: a term is {TERM_FLOATS} floats");
    assert_eq!((out.rows, plan.cols(out.id)), (rays, 3), "pinhole_rays {label}: out is not {rays} rays");
    let params = RaysParams {
        views: views as u32,
        height: height as u32,
        width: width as u32,
        terms_ld: plan.ld(terms.id) as u32,
        out_ld: plan.ld(out.id) as u32,
        zero: 0,
    };
    plan.push(Op {
        label: label.to_string(),
        shader: &RAYS,
        entry: "pinhole_rays",
        params: params.words(),
        bindings: vec![(terms, Access::Read), (out, Access::ReadWrite)],
        textures: Vec::new(),
        workgroups: grid(rays.div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}

/// Whether `gpu` makes pinhole rays bit-equal to the host's, found once per GPU by making a probe camera's rays
/// of both kinds there. A shader compiler that rewrote the kernel's error-free sums, or a float32 operation not
/// correctly rounded, would show in them; where it does, renders upload the rays the host makes instead.
pub async fn exact_on(gpu: &Gpu) -> bool {
    if let Some(&exact) = gpu.exact_pinhole_rays.get() {
        return exact;
    }
    // Two first renders at once may both probe; they find the same answer.
    let exact = probe(gpu).await.unwrap_or(false);
    *gpu.exact_pinhole_rays.get_or_init(|| exact)
}

async fn probe(gpu: &Gpu) -> Result<bool> {
    let pinhole = Intrinsics { width: 37, height: 23, fx: 29.3, fy: 31.7, cx: 17.9, cy: 12.2 };
    // A rotation with no zero entry (about the axis (1, 2, 3), by 0.7 radians), as columns.
    let (axis, (s, c)) = ([1.0, 2.0, 3.0].map(|v: f64| v / 14f64.sqrt()), 0.7f64.sin_cos());
    let rotation: [[f64; 3]; 3] = std::array::from_fn(|j| {
        std::array::from_fn(|i| {
            let cross = [[0.0, axis[2], -axis[1]], [-axis[2], 0.0, axis[0]], [axis[1], -axis[0], 0.0]][j][i];
            (1.0 - c) * axis[i] * axis[j] + if i == j { c } else { s * cross }
        })
    });
    for kind in [RayKind::UnitDirection, RayKind::UnitDepthPoint] {
        let camera = PinholeRays::new(kind, &pinhole, rotation, [1.7, -3.1, 2.9]);
        let (height, width) = (camera.height(), camera.width());
        let terms: Vec<f32> = camera.gpu_terms(0..width, 0..height).flatten().collect();
        let terms = gpu.upload("probe terms", width + height, TERM_FLOATS, &terms)?;
        let out = gpu.upload("probe rays", height * width, padded_cols(3), &vec![0.0; height * width * 4])?;
        let out = crate::tensor::GpuTensor { cols: 3, ..out };
        let mut b = PlanBuilder::new();
        let (t, o) = (b.external("terms", &terms), b.external("rays", &out));
        let args = PinholeRaysArgs { terms: b.all(t), views: 1, height, width, out: b.all(o) };
        pinhole_rays(&mut b, "probe", args);
        b.build(gpu)?.execute(gpu);
        let got = gpu.read_rows_async(&out.buffer, 0, height * width, padded_cols(3)).await?;
        let want = (0..height).flat_map(|i| (0..width).map(move |j| (i, j))).map(|(i, j)| camera.ray(i, j));
        if !got.chunks_exact(4).zip(want).all(|(g, w)| g[..3].iter().zip(w).all(|(a, b)| a.to_bits() == b.to_bits())) {
            return Ok(false);
        }
    }
    Ok(true)
}
