//! Kernel wrappers: each records one op of its WGSL kernel family into a [`PlanBuilder`](crate::plan::PlanBuilder).
//!
//! Conventions shared by every kernel (`shaders/README.md` has them from the shader side):
//! - binding 0 is the op's params: a uniform `struct Params` of 32-bit scalars (and, for posenc, an array
//!   of vec4s), mirrored field for field by a `#[repr(C)]` Rust struct declared with `params!`;
//!   `tests/uniforms.rs` checks that both sides agree. Tensors follow from binding 1;
//! - tensors are row-major `[rows, cols]` with rows padded to `ld = round_up(cols, 4)`; a kernel writes
//!   zeros into the padding of the rows it produces;
//! - images are NHWC: one row per pixel, one column per channel;
//! - workgroups are laid out with [`grid`](crate::plan::grid); a kernel takes its flat group index as
//!   `wid.x + wid.y * nwg.x` and returns early past the end.
//!
//! Each op also records its multiply-adds ([`Op::multiply_adds`](crate::plan::Op::multiply_adds)).

/// One field of a kernel's uniform as Rust lays it out: its name, byte offset and type as written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field {
    pub name: &'static str,
    pub offset: usize,
    pub ty: &'static str,
}

/// A code a shader reads from a `Params` field (an activation, a convolution mode, a map, a ray kind), as the
/// named WGSL constant the shader compares with and the value the wrapper writes. The wrapper's value is the
/// one source; `tests/uniforms.rs` checks that the shader declares the constant with that value, and that every
/// constant of the code's family in the shader is listed here ([`SHADER_CODES`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShaderCode {
    /// The shader (an [`ALL_SHADERS`] name) whose source declares the constant.
    pub shader: &'static str,
    /// The WGSL constant, e.g. `ACT_GELU`.
    pub name: &'static str,
    pub value: f64,
}

/// Every code the shaders share with the wrappers, each variant once.
pub fn shader_codes() -> Vec<ShaderCode> {
    let code = |shader, (name, value): (&'static str, f64)| ShaderCode { shader, name, value };
    let activations = [Activation::None, Activation::Relu, Activation::LeakyRelu(0.0), Activation::Gelu];
    let modes = [ConvMode::Overwrite, ConvMode::Accumulate, ConvMode::Residual];
    let kinds = [raypatch_model::RayKind::UnitDirection, raypatch_model::RayKind::UnitDepthPoint];
    // The activation prelude's constants, seen through a shader it is prepended to.
    (activations.iter().map(|a| code("elementwise", a.constant())))
        .chain(modes.iter().map(|m| code("elementwise", m.constant())))
        .chain(elementwise::Map::ALL.iter().map(|m| code("elementwise", m.constant())))
        .chain(kinds.iter().map(|&k| code("rays", rays::kind_constant(k))))
        .collect()
}

/// A kernel's uniform as Rust declares it, to compare with its shader's `Params` (`tests/uniforms.rs`).
#[derive(Clone, Copy, Debug)]
pub struct ParamsLayout {
    /// The Rust struct's name.
    pub name: &'static str,
    pub fields: &'static [Field],
    /// `size_of` the struct in bytes.
    pub size: usize,
}

/// Declares a kernel's uniform: a `#[repr(C)]` [`bytemuck::Pod`] struct that mirrors the shader's
/// `struct Params` field for field (same names, same order, f32 fields as `f32`), and its
/// [`ParamsLayout`] as the associated const `LAYOUT` (names, `offset_of!` offsets, types).
macro_rules! params {
    ($(#[$meta:meta])* $name:ident { $($(#[$fmeta:meta])* $field:ident: $ty:ty,)* }) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
        pub struct $name {
            $($(#[$fmeta])* pub $field: $ty,)*
        }

        impl $name {
            pub const LAYOUT: $crate::kernels::ParamsLayout = $crate::kernels::ParamsLayout {
                name: stringify!($name),
                fields: &[$($crate::kernels::Field {
                    name: stringify!($field),
                    offset: std::mem::offset_of!($name, $field),
                    ty: stringify!($ty),
                },)*],
                size: std::mem::size_of::<$name>(),
            };

            /// The uniform as the 32-bit words [`Op::params`](crate::plan::Op::params) holds.
            pub fn words(&self) -> Vec<u32> {
                bytemuck::cast_slice(std::slice::from_ref(self)).to_vec()
            }
        }
    };
}

pub mod attention;
pub mod concat;
pub mod conv;
pub mod copy;
pub mod elementwise;
pub mod gru;
pub mod matmul;
pub mod mix;
pub mod norm;
pub mod pack;
pub mod pool;
pub mod posenc;
pub mod rays;
pub mod readout;
pub mod resize;
pub mod softmax;

use crate::device::COOP_FEATURES;
use crate::gpu::Shader;
use crate::plan::{TensorId, View};

/// Activation fused into the end of a matmul or convolution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    None,
    Relu,
    LeakyRelu(f32),
    /// Exact GELU: x · Φ(x) with the erf form.
    Gelu,
}

impl Activation {
    /// The `ACT_*` constant of `shaders/activation.wgsl` and its value ([`ShaderCode`]).
    fn constant(self) -> (&'static str, f64) {
        match self {
            Activation::None => ("ACT_NONE", 0.0),
            Activation::Relu => ("ACT_RELU", 1.0),
            Activation::LeakyRelu(_) => ("ACT_LEAKY_RELU", 2.0),
            Activation::Gelu => ("ACT_GELU", 3.0),
        }
    }

    /// (code, slope) as the shaders' `Params` hold them.
    pub fn params(self) -> (u32, f32) {
        let slope = if let Activation::LeakyRelu(slope) = self { slope } else { 0.0 };
        (self.constant().1 as u32, slope)
    }
}

/// A square sliding window over an image, as PyTorch's `kernel_size`, `stride` and `padding` of
/// `nn.Conv2d` and `nn.MaxPool2d` (the same along both axes; no dilation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// `kernel × kernel` taps.
    pub kernel: usize,
    /// At least 1.
    pub stride: usize,
    /// Added on every side: zeros for a convolution, −∞ for a max pool.
    pub padding: usize,
}

impl Window {
    pub fn new(kernel: usize, stride: usize, padding: usize) -> Window {
        Window { kernel, stride, padding }
    }

    /// The output length along an axis of `len` input pixels, PyTorch's `floor((len + 2·padding − kernel) /
    /// stride) + 1` (`ceil_mode=False`); `None` when the padded input is shorter than the kernel (PyTorch
    /// refuses it) or the kernel or stride is 0.
    pub fn output(&self, len: usize) -> Option<usize> {
        if self.kernel == 0 || self.stride == 0 {
            return None;
        }
        (len + 2 * self.padding).checked_sub(self.kernel).map(|r| r / self.stride + 1)
    }
}

/// How a convolution's result meets what `out` already holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConvMode {
    /// `out = act(conv(x) + b)`.
    Overwrite,
    /// `out += act(conv(x) + b)` (the Ray-Patch decoder's rgb skips).
    Accumulate,
    /// `out = act(out + conv(x) + b)`: a residual block's sum before its activation (torchvision
    /// `BasicBlock`: `relu(bn2(conv2(h)) + identity)`, with the identity in `out`: the downsample conv's
    /// output, or the block's input itself when nothing reads it afterwards).
    Residual,
}

impl ConvMode {
    /// The `MODE_*` constant of `shaders/activation.wgsl` and its value ([`ShaderCode`]).
    fn constant(self) -> (&'static str, f64) {
        match self {
            ConvMode::Overwrite => ("MODE_OVERWRITE", 0.0),
            ConvMode::Accumulate => ("MODE_ACCUMULATE", 1.0),
            ConvMode::Residual => ("MODE_RESIDUAL", 2.0),
        }
    }

    /// `mode` as the shader's `Params` holds it.
    pub fn code(self) -> u32 {
        self.constant().1 as u32
    }

    /// Whether the kernel reads `out`.
    pub fn reads_out(self) -> bool {
        self != ConvMode::Overwrite
    }
}

/// A convolution's operands and options: see [`conv::conv2d`]. `matmul_lanes`' implicit GEMM takes them too
/// (`matmul::gemm_lanes`, also for linear layers as 1×1 convolutions over a 1 × M image).
#[derive(Clone, Copy, Debug)]
pub struct Conv2dArgs {
    /// `[n*h*w, cin]` NHWC view.
    pub x: View,
    pub n: usize,
    pub h: usize,
    pub w: usize,
    pub cin: usize,
    /// [`conv::pack_conv`]'s `[cout, k*k * padded_cols(cin)]` matrix.
    pub weight: TensorId,
    /// `[1, cout]` tensor.
    pub bias: Option<TensorId>,
    /// `[n*ho*wo, cout]` NHWC view.
    pub out: View,
    pub cout: usize,
    /// Kernel size, stride (>= 1) and zero padding.
    pub window: Window,
    /// Upsample the input 2× (nearest) before the convolution.
    pub upsample_input: bool,
    pub act: Activation,
    pub mode: ConvMode,
}

/// The output size `(ho, wo)` of a convolution with `window` over an `h × w` image (`2h × 2w` when
/// `upsample_input`), PyTorch's `(h_eff + 2·padding − k) / stride + 1`; `None` when the window does not fit.
pub fn conv_output_size(h: usize, w: usize, window: Window, upsample_input: bool) -> Option<(usize, usize)> {
    let up = usize::from(upsample_input);
    Some((window.output(h << up)?, window.output(w << up)?))
}

/// A shader from `shaders/FILE.wgsl`, optionally preceded by shared WGSL files (WGSL has no includes), called
/// NAME (pipelines are cached by name: one name per source).
macro_rules! shader {
    ($name:expr, $file:literal, $features:expr $(, $prelude:literal)*) => {
        Shader {
            name: $name,
            source: concat!(
                $(include_str!(concat!("../../../../shaders/", $prelude, ".wgsl")), "\n",)*
                include_str!(concat!("../../../../shaders/", $file, ".wgsl"))
            ),
            prefix: "",
            replace: &[],
            features: $features,
        }
    };
}

/// A `shaders!` entry's name: its `as` name where it has one, else its file's.
macro_rules! shader_name {
    ($file:literal) => {
        $file
    };
    ($file:literal, $alias:literal) => {
        $alias
    };
}

/// The one list of shaders: each line declares a `pub static` [`Shader`] and pairs it with the Rust
/// struct of its uniform; [`ALL_SHADERS`], [`VARIANTS`] and [`UNIFORMS`] are made from it.
/// - under `shaders`, `NAME = "file" [as "name"] ["prelude", ...] [needs FEATURES] => Params`: `shaders/file.wgsl`
///   after the preludes, needing optional wgpu features, called `file` or, where two entries share the file
///   with other preludes, `name`;
/// - under `variants`, `NAME = BASE { name, prefix, replace, features } => Params`: BASE's source
///   compiled with a prefix and text replacements, for optional features or fixed sizes.
macro_rules! shaders {
    (
        shaders {
            $($(#[$meta:meta])* $name:ident = $file:literal $(as $alias:literal)? [$($prelude:literal),*]
                $(needs $needs:expr)? => $params:ty;)*
        }
        variants {
            $($(#[$vmeta:meta])* $vname:ident = $base:ident {
                name: $vfile:literal, prefix: $prefix:expr, replace: $replace:expr, features: $features:expr $(,)?
            } => $vparams:ty;)*
        }
    ) => {
        $($(#[$meta])* pub static $name: Shader = shader!(
            shader_name!($file $(, $alias)?),
            $file,
            wgpu::Features::empty() $(.union($needs))?
            $(, $prelude)*
        );)*
        $($(#[$vmeta])* pub static $vname: Shader = Shader {
            name: $vfile,
            source: $base.source,
            prefix: $prefix,
            replace: $replace,
            features: $features,
        };)*

        const SHADER_COUNT: usize = [$(stringify!($name)),*].len();
        const VARIANT_COUNT: usize = [$(stringify!($vname)),*].len();

        /// Every shader, for validation tests and pipeline warm-up.
        pub static ALL_SHADERS: [&Shader; SHADER_COUNT] = [$(&$name),*];

        /// Variants of the shaders above: other features or fixed sizes.
        pub static VARIANTS: [&Shader; VARIANT_COUNT] = [$(&$vname),*];

        /// Every shader and variant with the Rust layout of its `Params` uniform (`tests/uniforms.rs`).
        pub static UNIFORMS: [(&Shader, ParamsLayout); SHADER_COUNT + VARIANT_COUNT] =
            [$((&$name, <$params>::LAYOUT),)* $((&$vname, <$vparams>::LAYOUT),)*];
    };
}

/// The replacement that makes `shaders/matmul.wgsl`'s weights f16 (widened to the tiles' type as they are loaded).
const F16_WEIGHTS: (&str, &str) = ("alias WeightVec = vec4<f32>;", "alias WeightVec = vec4<f16>;");

/// The replacement that makes `shaders/tiles.wgsl`'s tiles f16: x and w rounded to f16 as they are staged, the
/// products summed in f32 (`Precision::F16Activations`).
const F16_TILES: (&str, &str) = ("alias TileFloat = f32;", "alias TileFloat = f16;");

/// The replacement that makes the tensor kernels' cooperative matrices 8x8 (`shaders/coop_size.wgsl`'s `CT` and
/// aliases).
const COOP_8: &[(&str, &str)] = &[(
    "const CT: u32 = 16u;\nalias CoopA = coop_mat16x16<f16, A>;\nalias CoopB = coop_mat16x16<f16, B>;\nalias CoopC = coop_mat16x16<f32, C>;",
    "const CT: u32 = 8u;\nalias CoopA = coop_mat8x8<f16, A>;\nalias CoopB = coop_mat8x8<f16, B>;\nalias CoopC = coop_mat8x8<f32, C>;",
)];

/// The replacements that size `shaders/attention_flash.wgsl`'s registers for heads of up to 64 and 32 floats.
const CHUNKS_16: (&str, &str) = ("const CHUNKS: u32 = 32u;", "const CHUNKS: u32 = 16u;");
const CHUNKS_8: (&str, &str) = ("const CHUNKS: u32 = 32u;", "const CHUNKS: u32 = 8u;");

shaders! {
    shaders {
        MATMUL = "matmul" ["activation", "tiles"] => matmul::MatmulParams;
        /// `matmul` with `linear_coop` (`MatmulKernel::Coop`: the cooperative-matrix GEMM of `coop_tiles`, after
        /// `coop_size`, which comes first for its `enable` directives), 16x16 tiles.
        MATMUL_COOP = "matmul" as "matmul_coop" ["coop_size", "coop_tiles", "matmul_coop", "activation", "tiles"]
            needs COOP_FEATURES => matmul::MatmulParams;
        /// `conv` with `conv_coop`, 16x16 tiles.
        CONV_COOP = "conv" as "conv_coop" ["coop_size", "coop_tiles", "conv_coop", "activation", "tiles"]
            needs COOP_FEATURES => conv::ConvParams;
        /// Flash attention on cooperative matrices (`attention_coop`), 16x16 tiles.
        ATTENTION_COOP = "attention_coop" ["coop_size", "attention_params"] needs COOP_FEATURES
            => attention::AttentionParams;
        /// The linear layer for CPU adapters: see `tools/codegen/gen_matmul_lanes.py`.
        MATMUL_LANES = "matmul_lanes" ["activation", "texels"] needs wgpu::Features::SUBGROUP
            => matmul::MatmulLanesParams;
        PACK = "pack" ["texels"] => pack::PackParams;
        ATTENTION = "attention" ["attention_params"] => attention::AttentionParams;
        /// Attention for GPUs, heads of up to 128 floats, a query row per invocation: see `kernels::attention`.
        ATTENTION_FLASH = "attention_flash" ["attention_params", "flash_one_lane"] => attention::AttentionParams;
        /// `attention_flash` with a query row over four lanes of a subgroup.
        ATTENTION_FLASH_LANES = "attention_flash" as "attention_flash_lanes" ["attention_params", "flash_subgroup_lanes"]
            needs wgpu::Features::SUBGROUP => attention::AttentionParams;
        LAYERNORM = "layernorm" ["row_reduce"] => norm::LayerNormParams;
        POSENC = "posenc" [] => posenc::PosencParams;
        RESIZE = "resize" [] => resize::ResizeParams;
        CONV = "conv" ["activation", "tiles"] => conv::ConvParams;
        POOL = "pool" [] => pool::PoolParams;
        ELEMENTWISE = "elementwise" ["activation"] => elementwise::ElementwiseParams;
        SOFTMAX = "softmax" ["row_reduce"] => softmax::SoftmaxParams;
        MIX = "mix" [] => mix::MixParams;
        CONCAT = "concat" [] => concat::ConcatParams;
        COPY = "copy" [] => copy::CopyParams;
        READOUT = "readout" [] => readout::ReadoutParams;
        RAYS = "rays" [] => rays::RaysParams;
        GRU = "gru" ["activation"] => gru::GruParams;
    }
    variants {
        /// `matmul` with f16 weights: the same source with the weights' vector type replaced (f32 arithmetic).
        MATMUL_F16 = MATMUL {
            name: "matmul_f16",
            prefix: "enable f16;\n",
            replace: &[F16_WEIGHTS],
            features: wgpu::Features::SHADER_F16,
        } => matmul::MatmulParams;
        /// `matmul_f16` whose `linear_tiled` stages x as f16 too (half the workgroup memory traffic).
        MATMUL_F16_ACT = MATMUL {
            name: "matmul_f16_act",
            prefix: "enable f16;\n",
            replace: &[F16_WEIGHTS, F16_TILES],
            features: wgpu::Features::SHADER_F16,
        } => matmul::MatmulParams;
        /// `matmul_coop` with f16 weights.
        MATMUL_COOP_F16 = MATMUL_COOP {
            name: "matmul_coop_f16",
            prefix: "",
            replace: &[F16_WEIGHTS],
            features: COOP_FEATURES,
        } => matmul::MatmulParams;
        /// The tensor kernels on 8x8 cooperative matrices (Apple's, Mesa lavapipe's).
        MATMUL_COOP_8 = MATMUL_COOP {
            name: "matmul_coop_8",
            prefix: "",
            replace: COOP_8,
            features: COOP_FEATURES,
        } => matmul::MatmulParams;
        MATMUL_COOP_F16_8 = MATMUL_COOP {
            name: "matmul_coop_f16_8",
            prefix: "",
            replace: &[F16_WEIGHTS, COOP_8[0]],
            features: COOP_FEATURES,
        } => matmul::MatmulParams;
        CONV_COOP_8 = CONV_COOP {
            name: "conv_coop_8",
            prefix: "",
            replace: COOP_8,
            features: COOP_FEATURES,
        } => conv::ConvParams;
        ATTENTION_COOP_8 = ATTENTION_COOP {
            name: "attention_coop_8",
            prefix: "",
            replace: COOP_8,
            features: COOP_FEATURES,
        } => attention::AttentionParams;
        /// `attention_flash` with registers for heads of up to 64 floats.
        ATTENTION_FLASH_16 = ATTENTION_FLASH {
            name: "attention_flash_16",
            prefix: "",
            replace: &[CHUNKS_16],
            features: wgpu::Features::empty(),
        } => attention::AttentionParams;
        /// `attention_flash` with registers for heads of up to 32 floats.
        ATTENTION_FLASH_8 = ATTENTION_FLASH {
            name: "attention_flash_8",
            prefix: "",
            replace: &[CHUNKS_8],
            features: wgpu::Features::empty(),
        } => attention::AttentionParams;
        /// `attention_flash_lanes` for heads of up to 64 floats.
        ATTENTION_FLASH_LANES_16 = ATTENTION_FLASH_LANES {
            name: "attention_flash_lanes_16",
            prefix: "",
            replace: &[CHUNKS_16],
            features: wgpu::Features::SUBGROUP,
        } => attention::AttentionParams;
        /// `attention_flash_lanes` for heads of up to 32 floats.
        ATTENTION_FLASH_LANES_8 = ATTENTION_FLASH_LANES {
            name: "attention_flash_lanes_8",
            prefix: "",
            replace: &[CHUNKS_8],
            features: wgpu::Features::SUBGROUP,
        } => attention::AttentionParams;
    }
}
