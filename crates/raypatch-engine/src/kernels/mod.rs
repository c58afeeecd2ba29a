//! Kernel wrappers: each records one op of its WGSL kernel family into a [`PlanBuilder`](crate::plan::PlanBuilder).
//!
//! Conventions shared by every kernel (see also `shaders/README.md`):
//! - binding 0 is the op's params (a uniform struct of 32-bit scalars); tensors follow from binding 1;
//! - tensors are row-major `[rows, cols]` with rows padded to `ld = round_up(cols, 4)`; a kernel writes
//!   zeros into the padding of the rows it produces;
//! - images are NHWC: one row per pixel, one column per channel;
//! - workgroups are laid out with [`grid`](crate::plan::grid); a kernel takes its flat group index as
//!   `wid.x + wid.y * nwg.x` and returns early past the end.

pub mod attention;
pub mod conv;
pub mod elementwise;
pub mod matmul;
pub mod norm;
pub mod posenc;
pub mod resize;

use crate::gpu::Shader;

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
    /// (code, slope) as the shaders read them: 0 none, 1 relu, 2 leaky relu, 3 gelu.
    pub fn params(self) -> [u32; 2] {
        match self {
            Activation::None => [0, 0],
            Activation::Relu => [1, 0],
            Activation::LeakyRelu(slope) => [2, slope.to_bits()],
            Activation::Gelu => [3, 0],
        }
    }
}

/// A shader from `shaders/NAME.wgsl`, optionally preceded by shared WGSL files (WGSL has no includes).
macro_rules! shader {
    ($name:literal $(, $prelude:literal)*) => {
        Shader {
            name: $name,
            source: concat!(
                $(include_str!(concat!("../../../../shaders/", $prelude, ".wgsl")), "\n",)*
                include_str!(concat!("../../../../shaders/", $name, ".wgsl"))
            ),
            prefix: "",
            replace: &[],
            features: wgpu::Features::empty(),
        }
    };
}

pub static MATMUL: Shader = shader!("matmul", "activation");
/// `matmul` with f16 weights: the same source with the weights' vector type replaced (f32 arithmetic).
pub static MATMUL_F16: Shader = Shader {
    name: "matmul_f16",
    prefix: "enable f16;\n",
    replace: &[("alias WeightVec = vec4<f32>;", "alias WeightVec = vec4<f16>;")],
    features: wgpu::Features::SHADER_F16,
    ..shader!("matmul", "activation")
};
pub static ATTENTION: Shader = shader!("attention");
pub static LAYERNORM: Shader = shader!("layernorm");
pub static POSENC: Shader = shader!("posenc");
pub static RESIZE: Shader = shader!("resize");
pub static CONV: Shader = shader!("conv", "activation");
pub static ELEMENTWISE: Shader = shader!("elementwise");

/// Variants of the shaders above that need optional features.
pub static VARIANTS: [&Shader; 1] = [&MATMUL_F16];

/// Every shader, for validation tests and pipeline warm-up.
pub static ALL_SHADERS: [&Shader; 7] = [&MATMUL, &ATTENTION, &LAYERNORM, &POSENC, &RESIZE, &CONV, &ELEMENTWISE];
