//! Linear layers: a matmul with bias, fused activation and an optional in-place residual add, in four
//! kernels that compute the same sums ([`MatmulKernel`]): `shaders/matmul.wgsl`'s `linear` (register tiles,
//! buffers only) and `linear_tiled` (workgroup-memory tiles, for GPUs), `shaders/matmul_coop.wgsl`'s `linear_coop`
//! (f16 cooperative matrices: the f16-act precision's tensor kernels, `shaders/coop_tiles.wgsl`), and `shaders/matmul_lanes.wgsl` (for
//! CPU adapters: textures and subgroup broadcasts), an implicit GEMM that runs convolutions too
//! (`gemm_lanes`, called by `kernels::conv` as well) and batches of GEMMs (`gemm_lanes_batched`: attention's
//! heads, `kernels::attention`).

use crate::device::{fixed_shapes, linear_tiles, linear_variant, splits_to_fill, CoopShape, MatmulKernel, TileElement};
use crate::gpu::Shader;
use crate::kernels::norm::{check_affine, layernorm, row_stats, LayerNormArgs};
use crate::kernels::pack::{self, Packing, Source};
use crate::kernels::{conv_output_size, Conv2dArgs, ConvMode};
use crate::kernels::{
    Activation, Window, MATMUL, MATMUL_COOP, MATMUL_COOP_8, MATMUL_COOP_F16, MATMUL_COOP_F16_8, MATMUL_F16,
    MATMUL_F16_ACT, MATMUL_LANES,
};
use crate::plan::{grid, Access, Op, PlanBuilder, TensorId, TextureRef, View, MAX_GROUPS_PER_DIM};
use crate::tensor::{padded_cols, Dtype};

/// Rows and columns (8-column groups) per row tile of `matmul_lanes`' workgroup (one subgroup of
/// [`LANES`](crate::device::LANES)), and the row tiles of the band one workgroup walks.
/// `tools/codegen/gen_matmul_lanes.py` reads these three and `LANES` from here to unroll the shader (its `ROWS`,
/// `GROUPS` = columns / lanes, `BAND`).
const LANES_ROWS: usize = 8;
pub(crate) const LANES_COLS: usize = 8 * 4;
const LANES_BAND: usize = 8;

/// Rows and columns of `out` one workgroup of `linear` computes: 64 invocations x 4 rows (`WG * ROWS` in
/// the shader) by an 8-column tile of w.
const ROWS_TILE: (usize, usize) = (256, 8);
/// Rows and columns of `out` one workgroup of `linear_tiled` or `conv_tiled` computes (`TILE` in
/// `shaders/tiles.wgsl`).
pub(crate) const TILED_TILE: usize = 128;

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
        /// `linear_tiled`: K in `splits` ranges of `k_split4` vec4s; `m_tiles` = ceil(m / tile).
        splits: u32,
        k_split4: u32,
        m_tiles: u32,
        /// `linear_tiled`: 1 when x's rows are layer-normalised as they are staged ([`RowNorm`]), with the
        /// statistics `row_stats` took of them.
        norm: u32,
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
    /// x's rows layer-normalised first: out = act(LN(x) · wᵀ + bias).
    pub norm: Option<RowNorm>,
}

/// A layer norm applied to x's rows before a linear layer (`nn.LayerNorm` over the last dimension): see
/// [`layernorm`].
#[derive(Clone, Copy, Debug)]
pub struct RowNorm {
    /// `[1, K]` tensors.
    pub gamma: TensorId,
    pub beta: TensorId,
    pub eps: f32,
}

/// out = act(x · wᵀ + bias), or out += act(x · wᵀ + bias) when `accumulate` (residual add in place).
///
/// x: `[M, K]` view; w: `[N, K]` tensor (PyTorch `nn.Linear` layout, rows padded with zeros), f32 or f16
/// (f16 weights are widened to f32 as they are loaded, and the arithmetic is f32, except where the plan asks for
/// f16 activations: `device::linear_tiles`);
/// bias: optional `[1, N]` tensor; out: `[M, N]` view (written with [`Access::Write`], or
/// [`Access::ReadWrite`] when accumulating). The activation is applied before the add. The padding
/// columns of `out` are written as zeros (when accumulating they are zero already and stay zero).
/// Records `M·N·K` multiply-adds. Runs on the plan's [`MatmulKernel`] (`plan.kernels.matmul`); `Lanes`
/// hands f16 weights and operands too large for its textures to `Rows`.
///
/// With `norm`, x's rows are layer-normalised first: on `Tiled` as `linear_tiled` stages them, from the statistics
/// a [`row_stats`] took of them (the normalised rows are never written), elsewhere by a [`layernorm`] into a
/// transient that the layer then reads.
pub fn linear(plan: &mut PlanBuilder, label: &str, args: LinearArgs) {
    let LinearArgs { x, weight: w, bias, out, act, accumulate, norm } = args;
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
    let k4 = padded_cols(k) / 4;
    let mut params = MatmulParams {
        m: m as u32,
        n: n as u32,
        k4: k4 as u32,
        n4: n4 as u32,
        act: act_code,
        slope,
        has_bias: bias.is_some() as u32,
        accumulate: accumulate as u32,
        w_ld4: (plan.ld(w) / 4) as u32,
        splits: 1,
        k_split4: k4 as u32,
        m_tiles: 1,
        norm: 0,
    };
    assert!(
        plan.dtype(x.id) == Dtype::F32 && bias.is_none_or(|b| plan.dtype(b) == Dtype::F32),
        "linear {label}: x and bias must be f32"
    );
    let as_conv = Conv2dArgs {
        x,
        n: 1,
        h: 1,
        w: m,
        cin: k,
        weight: w,
        bias,
        out,
        cout: n,
        window: Window::new(1, 1, 0),
        upsample_input: false,
        act,
        mode: if accumulate { ConvMode::Accumulate } else { ConvMode::Overwrite },
    };
    let rows_groups = m.div_ceil(ROWS_TILE.0) * padded_cols(n).div_ceil(ROWS_TILE.1);
    let f32_weights = plan.dtype(w) == Dtype::F32;
    let variant = linear_variant(&plan.kernels, n, rows_groups, f32_weights, || lanes_fit(plan, &as_conv));
    let tiles = linear_tiles(&plan.kernels, variant, plan.dtype(w) == Dtype::F16);
    if let (Some(RowNorm { gamma, beta, eps }), false) =
        (norm, matches!(variant, MatmulKernel::Tiled | MatmulKernel::Coop))
    {
        let normed = plan.transient(&format!("{label}.norm"), m, k);
        let normed = plan.all(normed);
        layernorm(plan, &format!("{label}.norm"), LayerNormArgs { x, gamma, beta, out: normed, eps });
        return linear(plan, label, LinearArgs { x: normed, norm: None, ..args });
    }
    let coop = plan.kernels.coop.filter(|_| variant == MatmulKernel::Coop);
    let (entry, (tile_rows, tile_cols)) = match (variant, coop) {
        (MatmulKernel::Lanes, _) => return gemm_lanes(plan, label, as_conv),
        (MatmulKernel::Tiled, _) => ("linear_tiled", (TILED_TILE, TILED_TILE)),
        (MatmulKernel::Coop, Some(shape)) => {
            let tiling = shape.tiling(m);
            ("linear_coop", (shape.tile_rows(tiling), shape.tile_cols(tiling)))
        }
        (MatmulKernel::Coop, None) => panic!("linear {label}: the tensor kernels run only where the device has them"),
        (MatmulKernel::Rows, _) => ("linear", ROWS_TILE),
    };
    let shader = match (variant, plan.dtype(w), tiles) {
        (MatmulKernel::Coop, dtype, _) => coop_shader(plan.kernels.coop, dtype),
        (_, Dtype::F32, _) => &MATMUL,
        (_, Dtype::F16, TileElement::F32) => &MATMUL_F16,
        (_, Dtype::F16, TileElement::F16) => &MATMUL_F16_ACT,
    };
    let groups = m.div_ceil(tile_rows) * padded_cols(n).div_ceil(tile_cols);
    params.m_tiles = m.div_ceil(tile_rows) as u32;
    let out_access = if accumulate { Access::ReadWrite } else { Access::Write };
    let (weight, bias) = (plan.all(w), plan.all(bias.unwrap_or(w)));
    let mut bindings = vec![(x, Access::Read), (weight, Access::Read), (bias, Access::Read)];
    if matches!(variant, MatmulKernel::Tiled | MatmulKernel::Coop) {
        // linear_tiled's and linear_coop's layer norm: gamma and beta at 5 and 6, the rows' statistics at 7 (w again when there is
        // no norm, unread).
        let (gamma, beta, stats) = match norm {
            Some(RowNorm { gamma, beta, eps }) => {
                check_affine(plan, &format!("linear {label}: layer norm"), k, gamma, beta, eps);
                params.norm = 1;
                let stats = plan.transient(&format!("{label}.stats"), m, 4);
                let stats = plan.all(stats);
                row_stats(plan, &format!("{label}.stats"), x, stats, eps);
                (plan.all(gamma), plan.all(beta), stats)
            }
            None => (weight, weight, weight),
        };
        bindings.extend([(gamma, Access::Read), (beta, Access::Read), (stats, Access::Read)]);
    }
    let multiply_adds = (m as u64) * (n as u64) * (k as u64);
    let (splits, k_split4) = match (variant, coop) {
        (MatmulKernel::Tiled, _) => split_k(groups, k4),
        (_, Some(shape)) => split_k_in_steps(groups, k4, shape.tiling(m).bk as usize / 4),
        _ => (1, k4),
    };
    (params.splits, params.k_split4) = (splits as u32, k_split4 as u32);
    // Split K: each range's raw sums into the partials, then one pass adding them up into out.
    let (written, op_label, op_groups) = if splits == 1 {
        ((out, out_access), label.to_string(), groups)
    } else {
        let partials = plan.transient(&format!("{label}.partials"), splits * m, padded_cols(n));
        ((plan.all(partials), Access::Write), format!("{label}.split"), groups * splits)
    };
    bindings.insert(3, written);
    let mut constants = if fixed_shapes(&plan.kernels, variant) { fixed_shape(&params) } else { Vec::new() };
    constants.extend(coop.iter().flat_map(|shape| shape.constants(shape.tiling(m))));
    plan.push(Op {
        label: op_label,
        shader,
        entry,
        params: params.words(),
        bindings,
        textures: Vec::new(),
        workgroups: grid(op_groups),
        constants: constants.clone(),
        multiply_adds,
    });
    if splits > 1 {
        plan.push(Op {
            label: format!("{label}.reduce"),
            shader,
            entry: "linear_reduce",
            params: params.words(),
            bindings: vec![(written.0, Access::Read), (weight, Access::Read), (bias, Access::Read), (out, out_access)],
            textures: Vec::new(),
            workgroups: grid((m * n4).div_ceil(64)),
            constants,
            multiply_adds: 0,
        });
    }
}

/// The override constants that fix `shaders/matmul.wgsl`'s op to `params`' layer (`SHAPED`, and the fields the
/// shader reads through its `op_*` accessors that a layer fixes: columns, depth, weight stride, flags). The rows,
/// the row tiles and the K split stay in the params, with `slope` and `eps`: they change with the render's size,
/// and a pipeline keyed on them would be compiled again for every view count, size, region and band.
pub fn fixed_shape(params: &MatmulParams) -> Vec<(&'static str, f64)> {
    let p = params;
    let fields = [
        ("SHAPED_N", p.n),
        ("SHAPED_K4", p.k4),
        ("SHAPED_N4", p.n4),
        ("SHAPED_ACT", p.act),
        ("SHAPED_HAS_BIAS", p.has_bias),
        ("SHAPED_ACCUMULATE", p.accumulate),
        ("SHAPED_W_LD4", p.w_ld4),
        ("SHAPED_NORM", p.norm),
    ];
    std::iter::once(("SHAPED", 1.0)).chain(fields.map(|(name, value)| (name, f64::from(value)))).collect()
}

/// Workgroups that keep a large GPU busy, two per multiprocessor of an H100 or H200 (132): a `linear_tiled` with
/// fewer output tiles than this has its K split among workgroups (on an H200, 300x1536x1536 in 8 ranges: 8.7
/// TMAC/s against 3.3 unsplit; cuBLAS 9.3; the GEMM lab of docs/PERFORMANCE.md).
const TILED_TARGET_GROUPS: usize = 264;
/// vec4s of K per step of `linear_tiled` (`TILE_K4` in `shaders/tiles.wgsl`).
const TILED_K4: usize = 2;
/// The fewest vec4s a K range may have (128 floats, 16 steps).
const TILED_MIN_SPLIT_K4: usize = 32;

/// How many ranges `linear_tiled` cuts a K of `k4` vec4s into for an output of `groups` tiles: enough for
/// `TILED_TARGET_GROUPS` workgroups, each range at least `TILED_MIN_SPLIT_K4` vec4s long.
pub fn k_splits(groups: usize, k4: usize) -> usize {
    splits_to_fill(groups, TILED_TARGET_GROUPS, k4 / TILED_MIN_SPLIT_K4)
}

/// How a `Tiled` GEMM (`linear_tiled`, `conv_tiled`, the GEMM lab's kernels) with an output of `groups` tiles
/// cuts a K of `k4` vec4s: ([`k_splits`] ranges of whole steps, vec4s a range), the last range possibly shorter;
/// (1, k4) when the tiles are enough.
pub fn split_k(groups: usize, k4: usize) -> (usize, usize) {
    split_k_in_steps(groups, k4, TILED_K4)
}

/// [`split_k`] for a GEMM whose steps are `step4` vec4s of K (the tensor kernels' `COOP_BK / 4`).
pub fn split_k_in_steps(groups: usize, k4: usize, step4: usize) -> (usize, usize) {
    let k_split4 = k4.div_ceil(k_splits(groups, k4)).div_ceil(step4) * step4;
    (k4.div_ceil(k_split4), k_split4)
}

/// The tensor kernels' linear layer for the device's cooperative-matrix size and the weights' type.
fn coop_shader(coop: Option<CoopShape>, weights: Dtype) -> &'static Shader {
    match (coop.map(|shape| shape.tile), weights) {
        (Some(8), Dtype::F32) => &MATMUL_COOP_8,
        (Some(8), Dtype::F16) => &MATMUL_COOP_F16_8,
        (_, Dtype::F32) => &MATMUL_COOP,
        (_, Dtype::F16) => &MATMUL_COOP_F16,
    }
}

params! {
    /// The uniform of `shaders/matmul_lanes.wgsl`.
    MatmulLanesParams {
        /// out is [m, n]: output pixels (rows) by channels.
        m: u32,
        n: u32,
        /// Texels per tap: per pixel of x, per tap of a column of w.
        k4p: u32,
        /// Texels per row of the x texture and per packed row of w.
        x_ld: u32,
        w_ld: u32,
        /// ld(n): floats per row of out.
        ldo: u32,
        act: u32,
        slope: f32,
        has_bias: u32,
        /// [`ConvMode::code`].
        mode: u32,
        /// The input image and the output's size.
        h: u32,
        w: u32,
        ho: u32,
        wo: u32,
        /// The window: k × k taps, stride, zero padding.
        k: u32,
        stride: u32,
        pad: u32,
        /// 1 when the input is upsampled 2× (nearest) first.
        up: u32,
        /// The zero row of the x texture.
        zero_row: u32,
        /// Where batch z's x and w start (texels) and its out (vec4s), and the columns of a row it stores.
        x_batch: u32,
        w_batch: u32,
        out_batch4: u32,
        store_cols: u32,
    }
}

/// Whether [`gemm_lanes`] can run a convolution (or a linear layer as a 1×1 one): its packed operands fit
/// in textures.
pub(crate) fn lanes_fit(plan: &PlanBuilder, args: &Conv2dArgs) -> bool {
    let w_packing = Packing::conv_weight(args.window.kernel * args.window.kernel);
    let w_texels = w_packing.texels(args.cout, plan.cols(args.weight));
    let (ho, wo) = conv_output_size(args.h, args.w, args.window, args.upsample_input).unwrap_or((0, 0));
    Packing::IMAGE.texels(args.x.rows, args.cin).max(w_texels) <= plan.kernels.max_texels
        && lanes_workgroups(args.n * ho * wo, args.cout, 1).is_some()
}

/// `matmul_lanes`' grid for `batches` GEMMs with an `m` x `n` out: x walks the column tiles, y the bands of
/// `LANES_BAND` row tiles, z the batches. None past the per-dimension limit.
pub(crate) fn lanes_workgroups(m: usize, n: usize, batches: usize) -> Option<[u32; 3]> {
    let x = n.div_ceil(LANES_COLS);
    let y = m.div_ceil(LANES_ROWS).div_ceil(LANES_BAND);
    let fits = |groups: usize| (1..=MAX_GROUPS_PER_DIM as usize).contains(&groups);
    (fits(x) && fits(y) && fits(batches)).then_some([x as u32, y as u32, batches as u32])
}

/// A convolution, or a linear layer as a 1×1 convolution over a 1 × M image, on `matmul_lanes`: x packed
/// into the plan's scratch texture 0 (one pixel per row, then a zero pixel) right before; w (8 rows
/// interleaved, each tap's channels padded to whole blocks) packed once and kept where it is a constant (a
/// model weight), else into scratch texture 1. Check [`lanes_fit`] first.
pub(crate) fn gemm_lanes(plan: &mut PlanBuilder, label: &str, args: Conv2dArgs) {
    let Conv2dArgs { x, n, h, w, cin, weight, bias, out, cout, window, upsample_input, act, mode } = args;
    let Window { kernel, stride, padding } = window;
    let (ho, wo) = conv_output_size(h, w, window, upsample_input).expect("the window fits (checked by the caller)");
    let taps = kernel * kernel;
    plan.scratch_texels(0, Packing::IMAGE.texels(x.rows, cin));
    pack::pack(plan, &format!("{label}.pack_x"), x, TextureRef::Scratch(0), Packing::IMAGE);
    let w_source = Source::all(plan, plan.all(weight));
    let w_texture = pack::packed(plan, &format!("{label}.pack_w"), w_source, 1, Packing::conv_weight(taps));
    let npix = n * ho * wo;
    let (act, slope) = act.params();
    let k4p = Packing::IMAGE.texels_per_row(cin);
    let ldo = padded_cols(cout) as u32;
    let params = MatmulLanesParams {
        m: npix as u32,
        n: cout as u32,
        k4p: k4p as u32,
        x_ld: k4p as u32,
        w_ld: (taps * k4p) as u32,
        ldo,
        act,
        slope,
        has_bias: bias.is_some() as u32,
        mode: mode.code(),
        h: h as u32,
        w: w as u32,
        ho: ho as u32,
        wo: wo as u32,
        k: kernel as u32,
        stride: stride as u32,
        pad: padding as u32,
        up: u32::from(upsample_input),
        zero_row: x.rows as u32,
        x_batch: 0,
        w_batch: 0,
        out_batch4: 0,
        store_cols: ldo,
    };
    let out_access = if mode.reads_out() { Access::ReadWrite } else { Access::Write };
    let bias = plan.all(bias.unwrap_or(weight));
    let multiply_adds = (npix as u64) * (cout as u64) * (taps as u64) * (cin as u64);
    push_gemm(plan, label, params, 1, [bias, out], out_access, [TextureRef::Scratch(0), w_texture], multiply_adds);
}

/// `batches` linear GEMMs on packed operands, `out_z = x_z · w_zᵀ` (no bias, no activation) for batch z
/// (`MatmulLanesParams::x_batch` ..): attention's heads (`kernels::attention`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct LanesBatch {
    /// Each out is `[m, n]`, a sum over `k` (x's and w's rows are packed in runs of `k` columns).
    pub m: usize,
    pub n: usize,
    pub k: usize,
    /// Texels per row of x and per packed row of w; where batch z starts in each (texels).
    pub x_ld: usize,
    pub x_batch: usize,
    pub w_ld: usize,
    pub w_batch: usize,
    /// Where batch z's out starts (floats, a multiple of 4), and the columns of its rows it writes.
    pub out_batch: usize,
    pub store_cols: usize,
    pub batches: usize,
}

/// Whether [`gemm_lanes_batched`]'s grid fits.
pub(crate) fn lanes_batch_fits(batch: &LanesBatch) -> bool {
    lanes_workgroups(batch.m, batch.n, batch.batches).is_some()
}

/// Runs a [`LanesBatch`] on `matmul_lanes`: x in the row layout, w in the 8-lane layout (`kernels::pack`),
/// out written where the batches store (padding columns of their rows included). `unread` is bound where
/// the bias would be (none is read): any tensor the op does not write.
pub(crate) fn gemm_lanes_batched(
    plan: &mut PlanBuilder,
    label: &str,
    batch: LanesBatch,
    [x, w]: [TextureRef; 2],
    out: View,
    unread: View,
) {
    assert!(batch.out_batch.is_multiple_of(4), "{label}: batches of out must start at whole vec4s");
    let word = |v: usize| u32::try_from(v).expect("matmul_lanes param exceeds u32");
    let params = MatmulLanesParams {
        m: word(batch.m),
        n: word(batch.n),
        k4p: word(Packing::ROWS.texels_per_row(batch.k)),
        x_ld: word(batch.x_ld),
        w_ld: word(batch.w_ld),
        ldo: word(plan.ld(out.id)),
        act: 0,
        slope: 0.0,
        has_bias: 0,
        mode: ConvMode::Overwrite.code(),
        h: 1,
        w: word(batch.m),
        ho: 1,
        wo: word(batch.m),
        k: 1,
        stride: 1,
        pad: 0,
        up: 0,
        zero_row: word(batch.m),
        x_batch: word(batch.x_batch),
        w_batch: word(batch.w_batch),
        out_batch4: word(batch.out_batch / 4),
        store_cols: word(batch.store_cols),
    };
    let multiply_adds = (batch.batches * batch.m * batch.n * batch.k) as u64;
    push_gemm(plan, label, params, batch.batches, [unread, out], Access::Write, [x, w], multiply_adds);
}

/// Records one `matmul_lanes.gemm` dispatch: bindings bias and out, textures x and w.
#[allow(clippy::too_many_arguments)]
fn push_gemm(
    plan: &mut PlanBuilder,
    label: &str,
    params: MatmulLanesParams,
    batches: usize,
    [bias, out]: [View; 2],
    out_access: Access,
    [x, w]: [TextureRef; 2],
    multiply_adds: u64,
) {
    let workgroups =
        lanes_workgroups(params.m as usize, params.n as usize, batches).expect("the grid fits (checked by the caller)");
    plan.push(Op {
        label: label.to_string(),
        shader: &MATMUL_LANES,
        entry: "gemm",
        params: params.words(),
        bindings: vec![(bias, Access::Read), (out, out_access)],
        textures: vec![(x, Access::Read), (w, Access::Read)],
        workgroups,
        constants: Vec::new(),
        multiply_adds,
    });
}
