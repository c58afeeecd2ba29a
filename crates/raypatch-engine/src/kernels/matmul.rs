//! Linear layers: a matmul with bias, fused activation and an optional in-place residual add, in two
//! kernels that compute the same sums: `shaders/matmul.wgsl` (register tiles, buffers only) and
//! `shaders/matmul_lanes.wgsl` (for CPU adapters: textures and subgroup broadcasts).

use crate::kernels::pack::{self, Layout};
use crate::kernels::{Activation, MATMUL, MATMUL_F16, MATMUL_LANES};
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, TextureRef, View};
use crate::tensor::{padded_cols, Dtype};

/// Which kernel linear layers run on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum MatmulKernel {
    /// `matmul.linear`: 4x8 outputs per invocation from storage buffers; any adapter, f32 or f16 weights.
    #[default]
    Rows,
    /// `matmul_lanes.linear`: invocations along N, operands packed into textures, rows of x handed between
    /// lanes by subgroup broadcasts. For CPU adapters (llvmpipe), where it is ~6x faster; needs subgroups of
    /// exactly 8 lanes. Layers with f16 weights, or operands too large for a texture, use `Rows`.
    Lanes,
}

impl MatmulKernel {
    /// The faster kernel on this adapter: `Lanes` on CPU adapters that can run it, `Rows` elsewhere.
    pub fn best_for(info: &wgpu::AdapterInfo, features: wgpu::Features) -> MatmulKernel {
        let cpu = info.device_type == wgpu::DeviceType::Cpu;
        if cpu && MatmulKernel::Lanes.supported(info, features).is_ok() {
            MatmulKernel::Lanes
        } else {
            MatmulKernel::Rows
        }
    }

    /// Whether the adapter can run this kernel, and if not why.
    pub fn supported(self, info: &wgpu::AdapterInfo, features: wgpu::Features) -> Result<(), String> {
        match self {
            MatmulKernel::Rows => Ok(()),
            MatmulKernel::Lanes if !features.contains(wgpu::Features::SUBGROUP) => {
                Err("the adapter has no subgroup operations".into())
            }
            MatmulKernel::Lanes if (info.subgroup_min_size, info.subgroup_max_size) != (LANES, LANES) => Err(format!(
                "needs subgroups of {LANES} lanes, the adapter's are {}..{}",
                info.subgroup_min_size, info.subgroup_max_size
            )),
            MatmulKernel::Lanes => Ok(()),
        }
    }
}

/// Lanes of `matmul_lanes`' workgroup (one subgroup), and its rows and 8-column groups per workgroup
/// (`tools/gen_matmul_lanes.py`).
const LANES: u32 = 8;
const LANES_ROWS: usize = 8;
const LANES_COLS: usize = 8 * 3;

/// Rows of `out` one workgroup computes: 64 invocations x 4 rows (`WG * ROWS` in the shader).
const ROWS_PER_GROUP: usize = 256;
/// Columns of `out` one workgroup computes: the shader's 8-column tile of w.
const COLS_PER_GROUP: usize = 8;

params! {
    /// The uniform of `shaders/matmul.wgsl` (and its f16 variant).
    MatmulParams {
        m: u32,
        n: u32,
        /// ld(K) / 4: vec4s per row of x and w.
        k4: u32,
        /// ld(N) / 4: vec4s per row of out.
        n4: u32,
        /// Activation code and slope ([`Activation::params`]).
        act: u32,
        slope: f32,
        has_bias: u32,
        accumulate: u32,
        /// vec4s per row of w: k4 for f32 weights; f16 rows are padded to 8 halves, so k4 or k4 + 1.
        w_ld4: u32,
    }
}

/// A linear layer's operands: see [`linear`].
#[derive(Clone, Copy, Debug)]
pub struct LinearArgs {
    /// `[M, K]` view.
    pub x: View,
    /// `[N, K]` tensor (PyTorch `nn.Linear` layout), f32 or f16.
    pub weight: TensorId,
    /// `[1, N]` tensor.
    pub bias: Option<TensorId>,
    /// `[M, N]` view.
    pub out: View,
    pub act: Activation,
    /// `out += ...` (residual add in place) instead of `out = ...`.
    pub accumulate: bool,
}

/// out = act(x · wᵀ + bias), or out += act(x · wᵀ + bias) when `accumulate` (residual add in place).
///
/// x: `[M, K]` view; w: `[N, K]` tensor (PyTorch `nn.Linear` layout, rows padded with zeros), f32 or f16
/// (f16 weights are widened to f32 as they are loaded; the arithmetic is f32 either way);
/// bias: optional `[1, N]` tensor; out: `[M, N]` view (written with [`Access::Write`], or
/// [`Access::ReadWrite`] when accumulating). The activation is applied before the add. The padding
/// columns of `out` are written as zeros (when accumulating they are zero already and stay zero).
/// Records `M·N·K` multiply-adds. Runs on the plan's [`MatmulKernel`] (`plan.kernels.matmul`).
pub fn linear(plan: &mut PlanBuilder, label: &str, args: LinearArgs) {
    let LinearArgs { x, weight: w, bias, out, act, accumulate } = args;
    let (m, k, n) = (x.rows, plan.cols(x.id), plan.rows(w));
    assert!(k > 0 && n > 0, "linear {label}: empty weight [{n}, {k}]");
    assert_eq!(plan.cols(w), k, "linear {label}: weight is [{n}, {}] but x has {k} columns", plan.cols(w));
    assert!(
        out.rows == m && plan.cols(out.id) == n,
        "linear {label}: out is [{}, {}], expected [{m}, {n}]",
        out.rows,
        plan.cols(out.id)
    );
    if let Some(b) = bias {
        assert!(
            plan.rows(b) == 1 && plan.cols(b) == n,
            "linear {label}: bias is [{}, {}], expected [1, {n}]",
            plan.rows(b),
            plan.cols(b)
        );
    }
    let (act_code, slope) = act.params();
    let n4 = padded_cols(n) / 4;
    let params = MatmulParams {
        m: m as u32,
        n: n as u32,
        k4: (padded_cols(k) / 4) as u32,
        n4: n4 as u32,
        act: act_code,
        slope,
        has_bias: bias.is_some() as u32,
        accumulate: accumulate as u32,
        w_ld4: (plan.ld(w) / 4) as u32,
    };
    assert!(
        plan.dtype(x.id) == Dtype::F32 && bias.is_none_or(|b| plan.dtype(b) == Dtype::F32),
        "linear {label}: x and bias must be f32"
    );
    let lanes_fit = pack::packed_texels(m, k, Layout::Rows).max(pack::packed_texels(n, k, Layout::Lanes8))
        <= plan.kernels.max_texels;
    if plan.kernels.matmul == MatmulKernel::Lanes && plan.dtype(w) == Dtype::F32 && lanes_fit {
        return linear_lanes(plan, label, args);
    }
    let shader = match plan.dtype(w) {
        Dtype::F32 => &MATMUL,
        Dtype::F16 => &MATMUL_F16,
    };
    let groups = m.div_ceil(ROWS_PER_GROUP) * padded_cols(n).div_ceil(COLS_PER_GROUP);
    let out_access = if accumulate { Access::ReadWrite } else { Access::Write };
    plan.push(Op {
        label: label.to_string(),
        shader,
        entry: "linear",
        params: params.words(),
        bindings: vec![
            (x, Access::Read),
            (plan.all(w), Access::Read),
            (plan.all(bias.unwrap_or(w)), Access::Read),
            (out, out_access),
        ],
        textures: Vec::new(),
        workgroups: grid(groups),
        multiply_adds: (m as u64) * (n as u64) * (k as u64),
    });
}

params! {
    /// The uniform of `shaders/matmul_lanes.wgsl`.
    MatmulLanesParams {
        m: u32,
        n: u32,
        /// Texels per packed row of x and w.
        k4p: u32,
        /// ld(N): floats per row of out.
        ldo: u32,
        act: u32,
        slope: f32,
        has_bias: u32,
        accumulate: u32,
    }
}

/// [`linear`] on `matmul_lanes`: x packed into the plan's scratch texture 0 (row layout) right before; a
/// model weight's 8-lane packing made once, any other w (attention keys, values) packed into scratch
/// texture 1.
fn linear_lanes(plan: &mut PlanBuilder, label: &str, args: LinearArgs) {
    let LinearArgs { x, weight: w, bias, out, act, accumulate } = args;
    let (m, k, n) = (x.rows, plan.cols(x.id), plan.rows(w));
    plan.scratch_texels(0, pack::packed_texels(m, k, Layout::Rows));
    pack::pack(plan, &format!("{label}.pack_x"), x, TextureRef::Scratch(0), Layout::Rows);
    let w_texture = if plan.is_weight(w) {
        TextureRef::PackedWeight(w)
    } else {
        plan.scratch_texels(1, pack::packed_texels(n, k, Layout::Lanes8));
        pack::pack(plan, &format!("{label}.pack_w"), plan.all(w), TextureRef::Scratch(1), Layout::Lanes8);
        TextureRef::Scratch(1)
    };
    let (act, slope) = act.params();
    let params = MatmulLanesParams {
        m: m as u32,
        n: n as u32,
        k4p: pack::texels_per_row(k) as u32,
        ldo: padded_cols(n) as u32,
        act,
        slope,
        has_bias: bias.is_some() as u32,
        accumulate: accumulate as u32,
    };
    let groups = m.div_ceil(LANES_ROWS) * n.div_ceil(LANES_COLS);
    let out_access = if accumulate { Access::ReadWrite } else { Access::Write };
    plan.push(Op {
        label: label.to_string(),
        shader: &MATMUL_LANES,
        entry: "linear",
        params: params.words(),
        bindings: vec![(plan.all(bias.unwrap_or(w)), Access::Read), (out, out_access)],
        textures: vec![(TextureRef::Scratch(0), Access::Read), (w_texture, Access::Read)],
        workgroups: grid(groups),
        multiply_adds: (m as u64) * (n as u64) * (k as u64),
    });
}
