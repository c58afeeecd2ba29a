//! `nn.Conv2d(cin, cout, k, stride, padding)` on NHWC images, optionally after a fused 2× nearest
//! `nn.Upsample`, with an eval-mode `nn.BatchNorm2d` that follows it folded into its weight and bias once,
//! here, when the weights are read.

use super::{Data, Layout, Vars};
use crate::error::Result;
use crate::graph::Param;
use crate::graph::{Graph, ImageSize, Tensor};
use crate::kernels::conv::conv2d;
use crate::kernels::{conv_output_size, Conv2dArgs, ConvMode};
use crate::kernels::{Activation, Window};

/// PyTorch's BatchNorm2d default.
pub const BATCH_NORM_EPS: f64 = 1e-5;

/// A convolution's hyper-parameters: PyTorch's `nn.Conv2d(cin, cout, kernel, stride, padding, bias)`, and
/// whether an `nn.Upsample(scale_factor=2)` (nearest) comes before it (fused into the conv's reads).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvSpec {
    pub cin: usize,
    pub cout: usize,
    pub window: Window,
    pub bias: bool,
    pub upsample_input: bool,
}

impl ConvSpec {
    /// `nn.Conv2d(cin, cout, kernel, stride, padding)`: with a bias (PyTorch's default), no upsampling.
    pub fn new(cin: usize, cout: usize, kernel: usize, stride: usize, padding: usize) -> ConvSpec {
        ConvSpec { cin, cout, window: Window { kernel, stride, padding }, bias: true, upsample_input: false }
    }

    /// `bias=False` (convs followed by a BatchNorm).
    pub fn no_bias(self) -> ConvSpec {
        ConvSpec { bias: false, ..self }
    }

    /// The input upsampled 2× (nearest) first: `nn.Upsample(scale_factor=2)` then the conv.
    pub fn after_upsample(self) -> ConvSpec {
        ConvSpec { upsample_input: true, ..self }
    }
}

pub struct Conv2d {
    pub path: String,
    /// `[cout, cin, k, k]`, BatchNorm folded.
    pub weight: Param,
    /// `[1, cout]`, BatchNorm folded (present when the conv or the BatchNorm has one).
    pub bias: Option<Param>,
    pub spec: ConvSpec,
}

impl Conv2d {
    /// The conv at `vars` (with a bias when `spec.bias`), and the BatchNorm at `batch_norm` folded in when
    /// given: w' = w·γ/√(σ²+ε), b' = β + (b − μ)·γ/√(σ²+ε), in float64.
    pub fn new(vars: &Vars, spec: ConvSpec, batch_norm: Option<Vars>) -> Result<Conv2d> {
        let ConvSpec { cin, cout, window, .. } = spec;
        let kernel = window.kernel;
        let per_channel = cin * kernel * kernel;
        let weight = vars.tensor("weight", &[cout, cin, kernel, kernel])?.data;
        let bias = if spec.bias { Some(vars.tensor("bias", &[cout])?.data) } else { None };
        let (weight, bias) = match batch_norm {
            None => (Data::F32(weight), bias.map(Data::F32)),
            Some(bn) => {
                let get = |name: &str| bn.tensor(name, &[cout]).map(|t| t.data);
                let (gamma, beta, mean, var) =
                    (get("weight")?, get("bias")?, get("running_mean")?, get("running_var")?);
                let mut folded_w: Vec<f64> = weight.iter().map(|&v| v as f64).collect();
                let mut folded_b = Vec::with_capacity(cout);
                for c in 0..cout {
                    let scale = gamma[c] as f64 / (var[c] as f64 + BATCH_NORM_EPS).sqrt();
                    folded_w[c * per_channel..(c + 1) * per_channel].iter_mut().for_each(|v| *v *= scale);
                    let b = bias.as_ref().map_or(0.0, |b| b[c] as f64);
                    folded_b.push(beta[c] as f64 + (b - mean[c] as f64) * scale);
                }
                (Data::F64(folded_w), Some(Data::F64(folded_b)))
            }
        };
        Ok(Conv2d {
            path: vars.path().to_string(),
            weight: vars.prepared("weight", Layout::Conv { cout, cin, kernel }, weight),
            bias: bias.map(|b| vars.prepared("bias", Layout::Row, b)),
            spec,
        })
    }

    /// The output size for an input of `size` (PyTorch's `(h + 2·padding − k) / stride + 1`, of `2h` after
    /// the upsampling). Panics when the window does not fit the (padded) input, as PyTorch refuses it.
    pub fn output(&self, size: ImageSize) -> ImageSize {
        let ConvSpec { window, upsample_input, .. } = self.spec;
        let Some((h, w)) = conv_output_size(size.h, size.w, window, upsample_input) else {
            panic!("{}: a {window:?} does not fit a {}x{} image", self.path, size.h, size.w);
        };
        ImageSize { h, w, ..size }
    }

    /// `act(conv(x) + b)` into a new image.
    pub fn forward(&self, g: &mut Graph, x: Tensor, act: Activation) -> Tensor {
        let out = g.image(&self.path, self.output(x.size()), self.spec.cout);
        self.forward_into(g, x, out, act, ConvMode::Overwrite);
        out
    }

    /// `out = act(conv(x) + b)`, `out += act(conv(x) + b)` or `out = act(out + conv(x) + b)`, as `mode` says.
    pub fn forward_into(&self, g: &mut Graph, x: Tensor, out: Tensor, act: Activation, mode: ConvMode) {
        let ImageSize { n, h, w } = x.size();
        let label = g.label(&self.path);
        let weight = g.param(&label, self.weight);
        let bias = self.bias.map(|b| g.param(&label, b));
        let ConvSpec { cin, cout, window, upsample_input, .. } = self.spec;
        let args = Conv2dArgs {
            x: x.view,
            n,
            h,
            w,
            cin,
            weight,
            bias,
            out: out.view,
            cout,
            window,
            upsample_input,
            act,
            mode,
        };
        conv2d(&mut g.b, &label, args);
    }
}
