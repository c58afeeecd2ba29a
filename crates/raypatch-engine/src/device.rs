//! Which kernel variant runs where, decided here and nowhere else. A [`Gpu`](crate::Gpu) makes its device
//! profile ([`KernelChoice`]: the matmul kernel family for its adapter, the texture room) once; every plan
//! copies it; each kernel wrapper works out its op's shape facts (whether the operands fit a kernel's
//! textures and grid) and asks here for the variant: [`linear_variant`], [`conv_variant`],
//! [`attention_variant`], and whether its pipeline is specialised to its shape: [`fixed_shapes`].
//!
//! The families: `Rows` (storage buffers and register tiles, any adapter), `Tiled` (workgroup-memory tiles:
//! GPUs), `Lanes` (packed textures and 8-lane subgroup broadcasts: llvmpipe), `Coop` (f16 cooperative matrices,
//! tensor cores: opt-in, linear layers only so far). Adding a variant is an arm here,
//! its WGSL entry point and its wrapper's dispatch; ARCHITECTURE.md "Adding a kernel variant".

/// Lanes of a subgroup `matmul_lanes` needs, exactly.
pub const LANES: u32 = 8;

/// Lanes of a subgroup that share a query row in flash attention's subgroup variant
/// (`shaders/flash_subgroup_lanes.wgsl`; tools/codegen/gen_attention.py reads this).
pub const FLASH_LANES: usize = 4;

/// The kernel family linear layers, convolutions and attention run on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum MatmulKernel {
    /// Storage buffers and register tiles: `matmul.linear` (4x8 outputs per invocation), `conv.conv2d`,
    /// the fused `attention.attention`. Any adapter, f32 or f16 weights.
    #[default]
    Rows,
    /// Workgroup-memory tiles, for GPUs: `matmul.linear_tiled` (128x128 tiles of out per 256 invocations),
    /// `conv.conv_tiled` (the same tiling as an implicit GEMM) and flash attention (`attention_flash`). Any
    /// adapter, f32 or f16 weights.
    Tiled,
    /// `matmul_lanes.gemm`: invocations along N, operands packed into textures, rows of x handed between
    /// lanes by subgroup broadcasts; attention as batched GEMMs on it. For CPU adapters (llvmpipe), where it is
    /// ~4x faster; needs subgroups of exactly 8 lanes. Ops it does not suit (f16 weights, operands too large
    /// for its textures or grid, convolutions with few channels, heads not a multiple of 32 wide) run as `Rows`.
    Lanes,
    /// `matmul_coop.linear_coop`: f16 cooperative matrices (tensor cores) on 64x64 tiles of out, x and w rounded to
    /// f16 as they are staged, the products summed in f32 ([`COOP_FEATURES`]). Opt-in only (never
    /// [`best_for`](Self::best_for)) until a GPU measurement decides; linear layers only: convolutions and
    /// attention run as on `Tiled` ([`beyond_linear`](Self::beyond_linear)).
    Coop,
}

/// What `Coop` needs: cooperative matrices, requested only where the adapter lists 16x16x16 f16 x f16 -> f32
/// (`Gpu::new`), f16 in shaders, and subgroups of exactly [`COOP_LANES`] lanes.
pub const COOP_FEATURES: wgpu::Features =
    wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX.union(wgpu::Features::SHADER_F16).union(wgpu::Features::SUBGROUP);

/// Lanes of a subgroup `linear_coop` needs: its 128 invocations must be its 4 subgroups, one per quarter of the
/// tile.
pub const COOP_LANES: u32 = 32;

/// Whether a cooperative-matrix configuration is `Coop`'s: 16x16x16, f16 operands, f32 accumulators.
pub fn coop_configuration(p: &wgpu::CooperativeMatrixProperties) -> bool {
    (p.m_size, p.n_size, p.k_size) == (16, 16, 16)
        && p.ab_type == wgpu::CooperativeScalarType::F16
        && p.cr_type == wgpu::CooperativeScalarType::F32
}

impl MatmulKernel {
    /// Every kernel.
    pub const ALL: [MatmulKernel; 4] =
        [MatmulKernel::Rows, MatmulKernel::Tiled, MatmulKernel::Lanes, MatmulKernel::Coop];

    /// The name `--matmul-kernel` takes.
    pub fn name(self) -> &'static str {
        match self {
            MatmulKernel::Rows => "rows",
            MatmulKernel::Tiled => "tiled",
            MatmulKernel::Lanes => "lanes",
            MatmulKernel::Coop => "coop",
        }
    }

    /// The kernel called `name` ([`name`](Self::name)).
    pub fn from_name(name: &str) -> Option<MatmulKernel> {
        MatmulKernel::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The kernel for this adapter: `Lanes` on CPU adapters that can run it, `Rows` on other CPU adapters
    /// (on llvmpipe the workgroup tiles of `Tiled` are emulated memory), `Tiled` on GPUs.
    pub fn best_for(info: &wgpu::AdapterInfo, features: wgpu::Features) -> MatmulKernel {
        let cpu = info.device_type == wgpu::DeviceType::Cpu;
        if !cpu {
            MatmulKernel::Tiled
        } else if MatmulKernel::Lanes.supported(info, features).is_ok() {
            MatmulKernel::Lanes
        } else {
            MatmulKernel::Rows
        }
    }

    /// Whether the adapter can run this kernel, and if not why.
    pub fn supported(self, info: &wgpu::AdapterInfo, features: wgpu::Features) -> Result<(), String> {
        match self {
            MatmulKernel::Rows | MatmulKernel::Tiled => Ok(()),
            MatmulKernel::Lanes if !features.contains(wgpu::Features::SUBGROUP) => {
                Err("the adapter has no subgroup operations".into())
            }
            MatmulKernel::Lanes if (info.subgroup_min_size, info.subgroup_max_size) != (LANES, LANES) => Err(format!(
                "needs subgroups of {LANES} lanes, the adapter's are {}..{}",
                info.subgroup_min_size, info.subgroup_max_size
            )),
            MatmulKernel::Lanes => Ok(()),
            MatmulKernel::Coop if !features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) => {
                Err("the adapter has no 16x16x16 f16 cooperative matrices with f32 accumulators".into())
            }
            MatmulKernel::Coop if !features.contains(COOP_FEATURES) => {
                Err("the adapter lacks f16 in shaders or subgroup operations".into())
            }
            MatmulKernel::Coop if (info.subgroup_min_size, info.subgroup_max_size) != (COOP_LANES, COOP_LANES) => {
                Err(format!(
                    "needs subgroups of {COOP_LANES} lanes, the adapter's are {}..{}",
                    info.subgroup_min_size, info.subgroup_max_size
                ))
            }
            MatmulKernel::Coop => Ok(()),
        }
    }

    /// The family convolutions and attention run on: `Coop` has linear layers only so far, the rest runs as on
    /// `Tiled`.
    pub fn beyond_linear(self) -> MatmulKernel {
        match self {
            MatmulKernel::Coop => MatmulKernel::Tiled,
            other => other,
        }
    }
}

/// The device profile every plan records against.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KernelChoice {
    pub matmul: MatmulKernel,
    /// Texels the adapter's largest texture holds (`TEXTURE_WIDTH` x its largest 2-D dimension): ops whose
    /// packed operands would not fit fall back to buffer kernels.
    pub max_texels: usize,
    /// The model's precision is `Precision::F16Activations`: `Tiled` linear layers with f16 weights stage their
    /// inputs as f16 ([`linear_tiles`]). Set per model, not by the adapter.
    pub f16_activations: bool,
    /// Linear layers and convolutions run on `matmul` wherever it can run them, rather than on another family
    /// where that suits their shape better ([`linear_variant`], [`conv_variant`]): how the kernel tests and
    /// `raypatch-bench --gemm` check each family.
    pub pinned: bool,
    /// Kernels with a subgroup variant may use it: the adapter has subgroup operations, in subgroups of at least
    /// [`FLASH_LANES`] lanes ([`KernelChoice::subgroups_suit`]), and they were not turned off
    /// (`GpuOptions::without_subgroups`, `--no-subgroups`). Flash attention then splits each query row over
    /// `FLASH_LANES` lanes ([`attention_variant`]).
    pub subgroups: bool,
    /// `Tiled` linear layers run on pipelines compiled for their shape ([`fixed_shapes`]): on GPUs. Not on CPU
    /// adapters, where `Tiled` runs only when forced (tests): llvmpipe takes seconds to compile each shape's
    /// `linear_tiled` (the golden tests on `Tiled` took 20 minutes instead of 6 from a cold shader cache once
    /// narrow layers ran there), so one pipeline serves every shape; the kernel tests set it there to check the
    /// shaped pipelines.
    pub shaped: bool,
    /// The adapter has 16x16x16 f16 x f16 -> f32 cooperative matrices and the device was created with them
    /// ([`COOP_FEATURES`]): `Coop` can run.
    pub coop: bool,
}

impl KernelChoice {
    /// Whether an adapter's subgroups suit the kernels' subgroup variants: it has subgroup operations, in
    /// subgroups of at least [`FLASH_LANES`] lanes.
    pub fn subgroups_suit(info: &wgpu::AdapterInfo, features: wgpu::Features) -> bool {
        features.contains(wgpu::Features::SUBGROUP) && info.subgroup_min_size as usize >= FLASH_LANES
    }
}

/// The variant of a linear layer with `cols` output columns that would take `rows_groups` workgroups on `Rows`:
/// `f32_weights` (f16 weights are read from buffers only) and `lanes_fit` (whether its operands fit
/// `matmul_lanes`' textures and grid; asked only on `Lanes`).
///
/// On `Tiled`, `linear_tiled`, faster than `Rows` on every shape measured (on an H200: 14.8 against 5.9 TMAC/s on
/// 4800x768x2304, 8.7 against 2.4 on 300x1536x1536 with K split; the GEMM lab of docs/PERFORMANCE.md), except
/// narrow outputs with many rows ([`narrow_on_rows`]).
pub fn linear_variant(
    choice: &KernelChoice,
    cols: usize,
    rows_groups: usize,
    f32_weights: bool,
    lanes_fit: impl FnOnce() -> bool,
) -> MatmulKernel {
    match choice.matmul {
        MatmulKernel::Lanes if f32_weights && lanes_fit() => MatmulKernel::Lanes,
        MatmulKernel::Lanes => MatmulKernel::Rows,
        MatmulKernel::Tiled if narrow_on_rows(choice, cols, rows_groups) => MatmulKernel::Rows,
        other => other,
    }
}

/// Output columns (channels) below which a linear layer or a convolution may leave `Tiled` for `Rows`
/// ([`narrow_on_rows`]).
pub const TILED_MIN_COLS: usize = 64;

/// Workgroups an op's `Rows` grid needs to leave `Tiled` ([`narrow_on_rows`]): one per multiprocessor of an H100 or
/// H200 (132).
pub const ROWS_MIN_GROUPS: usize = 132;

/// Whether an op on `Tiled` with `cols` output columns (or channels), which would take `rows_groups` workgroups on
/// `Rows`, runs on `Rows` instead: outputs under [`TILED_MIN_COLS`] whose `Rows` grid fills a GPU
/// ([`ROWS_MIN_GROUPS`]); never when the choice is pinned.
///
/// A `Tiled` tile is 128 columns wide, so narrow outputs throw most of its work away: the Ray-Patch decoders'
/// convolutions (32, 16 and 8 feature channels, 3 or 1 image channels) took 1.15 of RP-SRT k=8's 4.27 ms and 4.97
/// of RP-DeFiNe k=16's 8.95 ms in the H200 breakdown of docs/PERFORMANCE.md, all on `conv_tiled`, for 0.28 and
/// 3.1 GMAC of useful work. `Rows` (8-column tiles) wastes little, but each of its invocations walks the whole of
/// K: with few workgroups the op is one chain of dependent loads, where `Tiled` splits K to fill the GPU. In the
/// same breakdown SRT's out_mlp.8 (4800x1536 to 3 a query chunk: 19 workgroups on `Rows`) took 0.44 ms a chunk
/// and RP-OSRT's mixing dots (300x1536 to 6: 2 workgroups) 0.81 ms, where `linear_tiled` with K split ran
/// 300x180x1536 at cuBLAS's rate.
pub fn narrow_on_rows(choice: &KernelChoice, cols: usize, rows_groups: usize) -> bool {
    !choice.pinned && cols < TILED_MIN_COLS && rows_groups >= ROWS_MIN_GROUPS
}

/// The variant of a convolution with `cout` output channels that would take `rows_groups` workgroups on `Rows`:
/// `lanes_suit` says whether `matmul_lanes` fits it and enough of its work is useful (asked only on `Lanes`). On
/// `Rows`, and where `Lanes` does not suit, the register-blocked direct kernel; on `Tiled`, `conv_tiled` except
/// narrow outputs over many pixels ([`narrow_on_rows`]: the Ray-Patch decoders' last, widest layers).
pub fn conv_variant(
    choice: &KernelChoice,
    cout: usize,
    rows_groups: usize,
    lanes_suit: impl FnOnce() -> bool,
) -> MatmulKernel {
    match choice.matmul.beyond_linear() {
        MatmulKernel::Lanes if lanes_suit() => MatmulKernel::Lanes,
        MatmulKernel::Lanes => MatmulKernel::Rows,
        MatmulKernel::Tiled if narrow_on_rows(choice, cout, rows_groups) => MatmulKernel::Rows,
        other => other,
    }
}

/// What a linear layer running on `variant` with f16 or f32 weights stages in its workgroup tiles: f16 (inputs
/// rounded to f16 as they are staged, the products summed in f32) where the model asks for f16 activations and
/// the layer runs on `Tiled` with f16 weights (a layer kept f32 for its range stays f32 throughout); else f32.
pub fn linear_tiles(choice: &KernelChoice, variant: MatmulKernel, f16_weights: bool) -> TileElement {
    if choice.f16_activations && variant == MatmulKernel::Tiled && f16_weights {
        TileElement::F16
    } else {
        TileElement::F32
    }
}

/// The element type of a `Tiled` GEMM's workgroup tiles (`TileFloat` in `shaders/tiles.wgsl`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TileElement {
    F32,
    F16,
}

/// Whether ops of this variant run on pipelines compiled for their own shape (override constants: `SHAPED` in
/// `shaders/matmul.wgsl`): on `Tiled` where the profile says so ([`KernelChoice::shaped`]: GPUs, whose drivers
/// compile a pipeline in milliseconds, once, then from the pipeline cache, and given the dimensions as constants
/// unroll and fold the K loop's bounds and strides).
pub fn fixed_shapes(choice: &KernelChoice, variant: MatmulKernel) -> bool {
    variant == MatmulKernel::Tiled && choice.shaped
}

/// Whether the kernels that reduce along rows (layer norm: `shaders/layernorm.wgsl`'s `layernorm_wide`; a row
/// softmax: `softmax.wgsl`'s `softmax_rows_wide`) take a workgroup per row, its max and sums combined in parallel,
/// rather than an invocation per row: on `Tiled`, the GPUs' family, where 300 rows on as many invocations would
/// leave a GPU idle while each walks its row; not on CPU adapters, whose invocations are SIMD lanes.
pub fn reduce_rows_per_workgroup(choice: &KernelChoice) -> bool {
    choice.matmul.beyond_linear() == MatmulKernel::Tiled
}

/// How attention runs ([`attention_variant`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AttentionVariant<L> {
    /// `attention.attention`: one fused dispatch, a head's 512 queries a workgroup.
    Fused,
    /// `attention_flash`: a workgroup per (64 queries, head, key split), each query row on `lanes` invocations
    /// (1, or [`FLASH_LANES`] lanes of a subgroup).
    Flash { lanes: usize },
    /// Scores, softmax and weighted values as batched `matmul_lanes` GEMMs, laid out as `L` says.
    Lanes(L),
}

/// The variant of an attention op with `queries` query rows: `lanes_layout` lays it out on `matmul_lanes`,
/// or says it does not suit it (asked only on `Lanes`).
pub fn attention_variant<L>(
    choice: &KernelChoice,
    queries: usize,
    lanes_layout: impl FnOnce() -> Option<L>,
) -> AttentionVariant<L> {
    match choice.matmul.beyond_linear() {
        _ if queries == 0 => AttentionVariant::Fused,
        MatmulKernel::Tiled => AttentionVariant::Flash { lanes: if choice.subgroups { FLASH_LANES } else { 1 } },
        MatmulKernel::Lanes => lanes_layout().map_or(AttentionVariant::Fused, AttentionVariant::Lanes),
        MatmulKernel::Rows | MatmulKernel::Coop => AttentionVariant::Fused,
    }
}

/// Into how many parts to split each of `groups` workgroups' work (keys, or K) so that about `target`
/// workgroups run, keeping a GPU's multiprocessors busy: at least 1, at most `most`.
pub fn splits_to_fill(groups: usize, target: usize, most: usize) -> usize {
    target.div_ceil(groups).min(most).max(1)
}
