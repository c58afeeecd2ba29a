//! Which kernel variant runs where, decided here and nowhere else. A [`Gpu`](crate::Gpu) makes its device
//! profile ([`KernelChoice`]: the matmul kernel family for its adapter, the texture room) once; every plan
//! copies it; each kernel wrapper works out its op's shape facts (whether the operands fit a kernel's
//! textures and grid) and asks here for the variant: [`linear_variant`], [`conv_variant`],
//! [`attention_variant`], and whether its pipeline is specialised to its shape: [`fixed_shapes`].
//!
//! The families: `Rows` (storage buffers and register tiles, any adapter), `Tiled` (workgroup-memory tiles:
//! GPUs), `Lanes` (packed textures and 8-lane subgroup broadcasts: llvmpipe), `Coop` (f16 cooperative matrices,
//! tensor cores, sized by [`CoopShape`]: the f16-act precision's kernels where the device has them). Adding a variant is an arm here,
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
    /// The tensor kernels: f16 cooperative matrices (tensor cores) sized for the adapter ([`CoopShape`]), the
    /// operands rounded to f16 as they are staged, the products summed in f32: `linear_coop`, `conv_coop`
    /// (`shaders/coop_tiles.wgsl`) and `attention_coop`. Where the model's precision is
    /// `Precision::F16Activations` and the device has them ([`KernelChoice::at_precision`]), or when forced.
    Coop,
}

/// What `Coop` needs: cooperative matrices (requested only where [`CoopShape::of_adapter`] finds a configuration
/// it can use), f16 in shaders, and subgroup operations (the subgroup's id and lane).
pub const COOP_FEATURES: wgpu::Features =
    wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX.union(wgpu::Features::SHADER_F16).union(wgpu::Features::SUBGROUP);

/// How the tensor kernels (`MatmulKernel::Coop`: `shaders/coop_tiles.wgsl`, `attention_coop.wgsl`) run on an
/// adapter: its cooperative-matrix tile and subgroup width, and the GEMM workgroups' tilings, which are the kernels'
/// override constants ([`constants`](Self::constants)), so that a tuner tries tilings without new code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CoopShape {
    /// The cooperative-matrix size, tile x tile x tile, f16 x f16 -> f32: 16 on NVIDIA and AMD, 8 on Apple and
    /// Mesa's lavapipe.
    pub tile: u32,
    /// The adapter's subgroup width (4 to 64), read from the adapter, never assumed.
    pub lanes: u32,
    /// The GEMM tiling of each shape class ([`GemmClass`]): the defaults, or the GPU kit's tuner's
    /// ([`COOP_TUNING_FILE`]).
    pub tilings: [CoopTiling; 2],
    /// The adapter's workgroup memory, in bytes: `attention_coop` runs where a head fits
    /// ([`attention_bytes`](Self::attention_bytes)).
    pub workgroup_bytes: u32,
}

/// A GEMM workgroup's tiling on the tensor kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CoopTiling {
    /// Subgroups along M and N; each computes a 2·tile x 2·tile block of out (2 x 2 accumulators).
    pub sg_m: u32,
    pub sg_n: u32,
    /// Floats of K a step stages (a multiple of the tile).
    pub bk: u32,
}

impl CoopTiling {
    /// The tilings an adapter starts from, best first: 2x2 subgroups staging two tiles of K a step, then one, then a
    /// single subgroup (WebGPU's default 16 KiB of workgroup memory).
    pub fn preferred(tile: u32) -> [CoopTiling; 3] {
        [(2, 2, 2 * tile), (2, 2, tile), (1, 1, tile)].map(|(sg_m, sg_n, bk)| CoopTiling { sg_m, sg_n, bk })
    }
}

/// The GEMM shape classes the tensor kernels' tilings are tuned for, by output rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GemmClass {
    /// Up to [`GemmClass::LARGE_ROWS`] rows: a Ray-Patch render's queries, slot attention.
    Small,
    /// More: per-pixel renders, encoders' pixels, batches of views.
    Large,
}

impl GemmClass {
    pub const LARGE_ROWS: usize = 2048;

    pub fn of_rows(rows: usize) -> GemmClass {
        if rows > GemmClass::LARGE_ROWS {
            GemmClass::Large
        } else {
            GemmClass::Small
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            GemmClass::Small => "small",
            GemmClass::Large => "large",
        }
    }
}

/// The file in raypatch's cache folder (`pipeline_cache::PipelineCacheDir`) where the GPU kit's tuner
/// (`tools/bench/gpu_bench.sh OUT tensor`) keeps the fastest tiling per adapter and shape class: a line
/// `adapter name<TAB>class<TAB>sg_m<TAB>sg_n<TAB>bk` each (class `small` or `large`); lines for other adapters,
/// and tilings that do not fit this one, are ignored.
pub const COOP_TUNING_FILE: &str = "coop-tuning.tsv";

impl CoopShape {
    /// The tensor kernels' shape on this adapter, or why they cannot run there: it must list an f16 x f16 -> f32
    /// configuration of 8x8x8 or 16x16x16 (16 preferred), have f16 in shaders and subgroups of one width, at least
    /// the tile's (an llvmpipe narrower than 256 bits lists the feature but has 4-lane subgroups, and making a
    /// device with it fails there), and room for the workgroup.
    pub fn of_adapter(
        info: &wgpu::AdapterInfo,
        features: wgpu::Features,
        configurations: &[wgpu::CooperativeMatrixProperties],
        limits: &wgpu::Limits,
    ) -> Result<CoopShape, String> {
        if !features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
            return Err("the adapter has no cooperative matrices".into());
        }
        if !features.contains(wgpu::Features::SHADER_F16 | wgpu::Features::SUBGROUP) {
            return Err("the adapter lacks f16 in shaders or subgroup operations".into());
        }
        let tile = [16, 8]
            .into_iter()
            .find(|&t| configurations.iter().any(|c| coop_configuration(c, t)))
            .ok_or("the adapter lists no 8x8x8 or 16x16x16 f16 x f16 -> f32 cooperative matrices")?;
        let (lanes, max_lanes) = (info.subgroup_min_size, info.subgroup_max_size);
        if lanes != max_lanes {
            return Err(format!("its subgroups are {lanes} to {max_lanes} lanes wide, not one fixed width"));
        }
        if !(4..=64).contains(&lanes) || lanes < tile {
            return Err(format!("its subgroups are {lanes} lanes wide, narrower than the {tile}x{tile} tile"));
        }
        if let Some(bits) = llvmpipe_bits(&info.name) {
            if bits < 256 {
                return Err(format!("llvmpipe at {bits} bits has no cooperative matrices (it needs 256: AVX2)"));
            }
        }
        let preferred = CoopTiling::preferred(tile)[0];
        let mut shape = CoopShape {
            tile,
            lanes,
            tilings: [preferred; 2],
            workgroup_bytes: limits.max_compute_workgroup_storage_size,
        };
        shape.tilings = [shape.default_tiling(limits)?; 2];
        Ok(shape)
    }

    /// The untuned tiling on an adapter with `limits`: the first of [`CoopTiling::preferred`] that fits them, or why
    /// none does.
    pub fn default_tiling(&self, limits: &wgpu::Limits) -> Result<CoopTiling, String> {
        let preferred = CoopTiling::preferred(self.tile);
        let fitting = preferred.into_iter().find(|&t| self.fits(t, limits).is_ok());
        fitting.ok_or_else(|| self.fits(preferred[2], limits).unwrap_err())
    }

    /// Whether `tiling` fits the adapter's limits: its invocations and its workgroup memory.
    pub fn fits(&self, tiling: CoopTiling, limits: &wgpu::Limits) -> Result<(), String> {
        let invocations = tiling.sg_m * tiling.sg_n * self.lanes;
        let rows = 2 * self.tile * (tiling.sg_m + tiling.sg_n);
        let bytes = 2 * rows * (tiling.bk + 8) * 2 + tiling.sg_m * tiling.sg_n * self.tile * self.tile * 4 + 4;
        if tiling.bk == 0 || tiling.bk % self.tile != 0 || tiling.sg_m == 0 || tiling.sg_n == 0 {
            Err(format!("tiling {tiling:?}: K steps must be whole tiles of {}", self.tile))
        } else if invocations > limits.max_compute_invocations_per_workgroup {
            Err(format!(
                "a workgroup of {invocations} invocations is more than the adapter's {}",
                limits.max_compute_invocations_per_workgroup
            ))
        } else if bytes > limits.max_compute_workgroup_storage_size {
            Err(format!(
                "{bytes} bytes of workgroup memory is more than the adapter's {}",
                limits.max_compute_workgroup_storage_size
            ))
        } else {
            Ok(())
        }
    }

    /// This shape with the tuned tilings `tuning` (the text of [`COOP_TUNING_FILE`]) lists for `adapter`, where
    /// they fit its limits.
    pub fn tuned(mut self, tuning: &str, adapter: &str, limits: &wgpu::Limits) -> CoopShape {
        for line in tuning.lines() {
            let fields: Vec<&str> = line.split('\t').collect();
            let [name, class, sg_m, sg_n, bk] = fields[..] else { continue };
            let class = match class {
                "small" => GemmClass::Small,
                "large" => GemmClass::Large,
                _ => continue,
            };
            let (Ok(sg_m), Ok(sg_n), Ok(bk)) = (sg_m.parse(), sg_n.parse(), bk.parse()) else { continue };
            let tiling = CoopTiling { sg_m, sg_n, bk };
            if name == adapter && sg_m <= 8 && sg_n <= 8 && bk <= 256 && self.fits(tiling, limits).is_ok() {
                self.tilings[class as usize] = tiling;
            }
        }
        self
    }

    /// Bytes of workgroup memory `attention_coop` takes for heads padded to `padded_head` floats (the shader's
    /// arrays: q, the keys or values, P, the scores or P·V, the output, the row reductions and statistics).
    pub fn attention_bytes(&self, padded_head: usize) -> usize {
        let (t, dh) = (self.tile as usize, padded_head);
        let halves = t * (dh + 8) + 4 * t * (dh + 8) + t * (4 * t + 8);
        2 * halves + 4 * (2 * t * dh + 4 * self.lanes as usize + 3 * t)
    }

    /// The head width `attention_coop` pads a head of `dim_head` floats to: whole output blocks of its four
    /// subgroups.
    pub fn padded_head(&self, dim_head: usize) -> usize {
        let block = 4 * self.tile as usize;
        dim_head.div_ceil(block) * block
    }

    /// The tiling of a GEMM with `rows` rows of out.
    pub fn tiling(&self, rows: usize) -> CoopTiling {
        self.tilings[GemmClass::of_rows(rows) as usize]
    }

    /// Rows and columns of out a GEMM workgroup of `tiling` computes.
    pub fn tile_rows(&self, tiling: CoopTiling) -> usize {
        (tiling.sg_m * 2 * self.tile) as usize
    }

    pub fn tile_cols(&self, tiling: CoopTiling) -> usize {
        (tiling.sg_n * 2 * self.tile) as usize
    }

    /// The GEMM's override constants for `tiling` (`shaders/coop_tiles.wgsl`).
    pub fn constants(&self, tiling: CoopTiling) -> Vec<(&'static str, f64)> {
        vec![
            ("COOP_LANES", f64::from(self.lanes)),
            ("COOP_SG_M", f64::from(tiling.sg_m)),
            ("COOP_SG_N", f64::from(tiling.sg_n)),
            ("COOP_BK", f64::from(tiling.bk)),
        ]
    }
}

/// The vector width llvmpipe names in its adapter name ("llvmpipe (LLVM 19.1.7, 256 bits)"), if it is llvmpipe.
fn llvmpipe_bits(name: &str) -> Option<u32> {
    let rest = name.strip_prefix("llvmpipe")?;
    let bits = rest.split(" bits").next()?.rsplit(|c: char| !c.is_ascii_digit()).next()?;
    bits.parse().ok()
}

/// Whether a cooperative-matrix configuration is a `tile`-sized one the tensor kernels use: f16 operands, f32
/// accumulators, at subgroup scope.
pub fn coop_configuration(p: &wgpu::CooperativeMatrixProperties, tile: u32) -> bool {
    (p.m_size, p.n_size, p.k_size) == (tile, tile, tile)
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
    /// (on llvmpipe the workgroup tiles of `Tiled` are emulated memory; in a browser, SwiftShader) and on GPUs whose
    /// limits `Tiled` does not fit, `Tiled` on other GPUs.
    pub fn best_for(info: &wgpu::AdapterInfo, features: wgpu::Features, limits: &wgpu::Limits) -> MatmulKernel {
        let cpu = info.device_type == wgpu::DeviceType::Cpu;
        if !cpu && MatmulKernel::Tiled.fits(limits).is_ok() {
            MatmulKernel::Tiled
        } else if !cpu {
            MatmulKernel::Rows
        } else if MatmulKernel::Lanes.supported(info, features).is_ok() {
            MatmulKernel::Lanes
        } else {
            MatmulKernel::Rows
        }
    }

    /// Whether a device with `limits` has room for this family's workgroups (their invocations and workgroup
    /// memory), and if not which limit is short. `Coop`'s tilings are fitted by [`CoopShape::fits`].
    pub fn fits(self, limits: &wgpu::Limits) -> Result<(), String> {
        let (invocations, bytes) = match self {
            MatmulKernel::Rows | MatmulKernel::Lanes | MatmulKernel::Coop => (ROWS_INVOCATIONS, 0),
            MatmulKernel::Tiled => (TILED_INVOCATIONS, TILED_WORKGROUP_BYTES),
        };
        let name = self.name();
        if invocations > limits.max_compute_invocations_per_workgroup {
            Err(format!(
                "the {name} kernels need {invocations} invocations per workgroup, the adapter's \
                 maxComputeInvocationsPerWorkgroup is {}",
                limits.max_compute_invocations_per_workgroup
            ))
        } else if bytes > limits.max_compute_workgroup_storage_size {
            Err(format!(
                "the {name} kernels need {bytes} bytes of workgroup memory, the adapter's \
                 maxComputeWorkgroupStorageSize is {}",
                limits.max_compute_workgroup_storage_size
            ))
        } else {
            Ok(())
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
            // The device has cooperative matrices only where CoopShape::of_adapter found a shape (Gpu::new).
            MatmulKernel::Coop if !features.contains(COOP_FEATURES) => {
                Err("the device has no cooperative matrices the tensor kernels can use".into())
            }
            MatmulKernel::Coop => Ok(()),
        }
    }
}

/// Storage buffers one kernel binds at most (`shaders/matmul.wgsl`; `device/tests.rs` counts every shader's): an
/// adapter needs this many per shader stage (WebGPU's default is 8; SwiftShader in Chromium has 10).
pub const STORAGE_BUFFERS_PER_STAGE: u32 = 7;

/// Invocations of the buffer kernels' workgroups (`WG` in the shaders: 64).
pub const ROWS_INVOCATIONS: u32 = 64;

/// Invocations of `Tiled`'s workgroups: 16x16 GEMM and convolution tiles, flash attention's 64 rows x 4 lanes.
pub const TILED_INVOCATIONS: u32 = 256;

/// Workgroup memory of `Tiled`'s kernels at most: flash attention's key and value tiles
/// (`shaders/attention_flash.wgsl`, 2 x 512 vec4 of f32); the GEMM tiles (`tiles.wgsl`) take half that.
pub const TILED_WORKGROUP_BYTES: u32 = 2 * 512 * 16;

/// Whether an adapter with `limits` can run the engine's kernels at all (every family binds up to
/// [`STORAGE_BUFFERS_PER_STAGE`] storage buffers and runs [`ROWS_INVOCATIONS`]-wide workgroups), and if not
/// which limit is short, by its WebGPU name.
pub fn check_limits(limits: &wgpu::Limits) -> Result<(), String> {
    if limits.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS_PER_STAGE {
        return Err(format!(
            "the kernels bind up to {STORAGE_BUFFERS_PER_STAGE} storage buffers per shader stage, the adapter's \
             maxStorageBuffersPerShaderStage is {}",
            limits.max_storage_buffers_per_shader_stage
        ));
    }
    MatmulKernel::Rows.fits(limits)
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
    /// The tensor kernels' shape where the device was created with cooperative matrices ([`COOP_FEATURES`],
    /// [`CoopShape::of_adapter`]): `Coop` can run.
    pub coop: Option<CoopShape>,
}

impl KernelChoice {
    /// The profile a model's plans record against: under `Precision::F16Activations` (`f16_activations`) every
    /// GEMM runs on the tensor kernels where the device has them (unless a kernel was forced: `pinned`); else
    /// as the adapter's profile says.
    pub fn at_precision(self, f16_activations: bool) -> KernelChoice {
        let coop = f16_activations && self.coop.is_some() && !self.pinned;
        KernelChoice { f16_activations, matmul: if coop { MatmulKernel::Coop } else { self.matmul }, ..self }
    }

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
        MatmulKernel::Tiled | MatmulKernel::Coop if narrow_on_rows(choice, cols, rows_groups) => MatmulKernel::Rows,
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
    match choice.matmul {
        MatmulKernel::Lanes if lanes_suit() => MatmulKernel::Lanes,
        MatmulKernel::Lanes => MatmulKernel::Rows,
        MatmulKernel::Tiled | MatmulKernel::Coop if narrow_on_rows(choice, cout, rows_groups) => MatmulKernel::Rows,
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
    matches!(variant, MatmulKernel::Tiled | MatmulKernel::Coop) && choice.shaped
}

/// Whether the kernels that reduce along rows (layer norm: `shaders/layernorm.wgsl`'s `layernorm_wide`; a row
/// softmax: `softmax.wgsl`'s `softmax_rows_wide`) take a workgroup per row, its max and sums combined in parallel,
/// rather than an invocation per row: on `Tiled`, the GPUs' family, where 300 rows on as many invocations would
/// leave a GPU idle while each walks its row; not on CPU adapters, whose invocations are SIMD lanes.
pub fn reduce_rows_per_workgroup(choice: &KernelChoice) -> bool {
    matches!(choice.matmul, MatmulKernel::Tiled | MatmulKernel::Coop)
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
    /// `attention_coop`: flash attention with both products on cooperative matrices, the online softmax in f32
    /// between them, for heads of up to [`COOP_MAX_DIM_HEAD`] floats whose tiles fit the workgroup memory.
    Coop(CoopShape),
}

/// The widest head `attention_coop` takes (its workgroup memory holds a query tile's head and output).
pub const COOP_MAX_DIM_HEAD: usize = 128;

/// The variant of an attention op with `queries` query rows and heads `dim_head` wide: `lanes_layout` lays it
/// out on `matmul_lanes`, or says it does not suit it (asked only on `Lanes`). On `Coop`, heads wider than
/// [`COOP_MAX_DIM_HEAD`] run as on `Tiled`.
pub fn attention_variant<L>(
    choice: &KernelChoice,
    queries: usize,
    dim_head: usize,
    lanes_layout: impl FnOnce() -> Option<L>,
) -> AttentionVariant<L> {
    let flash = AttentionVariant::Flash { lanes: if choice.subgroups { FLASH_LANES } else { 1 } };
    match choice.matmul {
        _ if queries == 0 => AttentionVariant::Fused,
        MatmulKernel::Coop => match choice.coop {
            Some(shape)
                if dim_head <= COOP_MAX_DIM_HEAD
                    && shape.attention_bytes(shape.padded_head(dim_head)) <= shape.workgroup_bytes as usize =>
            {
                AttentionVariant::Coop(shape)
            }
            _ => flash,
        },
        MatmulKernel::Tiled => flash,
        MatmulKernel::Lanes => lanes_layout().map_or(AttentionVariant::Fused, AttentionVariant::Lanes),
        MatmulKernel::Rows => AttentionVariant::Fused,
    }
}

/// Into how many parts to split each of `groups` workgroups' work (keys, or K) so that about `target`
/// workgroups run, keeping a GPU's multiprocessors busy: at least 1, at most `most`.
pub fn splits_to_fill(groups: usize, target: usize, most: usize) -> usize {
    target.div_ceil(groups).min(most).max(1)
}

#[cfg(test)]
mod tests;
