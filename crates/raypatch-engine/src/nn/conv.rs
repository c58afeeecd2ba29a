//! `nn.Conv2d(cin, cout, 3, padding=1)` on NHWC images, with an eval-mode `nn.BatchNorm2d` that follows it
//! folded into its weight and bias once, here, when the weights are read.

use super::{Data, Layout, Param, Vars};
use crate::error::Result;
use crate::graph::{Graph, ImageSize, Tensor};
use crate::kernels::conv::{conv3x3, Conv3x3Args};
use crate::kernels::Activation;

/// PyTorch's BatchNorm2d default.
pub const BATCH_NORM_EPS: f64 = 1e-5;

/// How a convolution changes the image size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Resample {
    /// Stride 1.
    Same,
    /// Stride 2: ceil(h/2) × ceil(w/2), as PyTorch's stride-2 3×3 conv with padding 1 at any size.
    Down2,
    /// The input nearest-upsampled 2× first (`nn.Upsample(scale_factor=2)` then the conv), fused.
    Up2,
}

impl Resample {
    pub fn output(self, size: ImageSize) -> ImageSize {
        match self {
            Resample::Same => size,
            Resample::Down2 => ImageSize { h: size.h.div_ceil(2), w: size.w.div_ceil(2), ..size },
            Resample::Up2 => ImageSize { h: 2 * size.h, w: 2 * size.w, ..size },
        }
    }
}

pub struct Conv3x3 {
    pub path: String,
    /// `[cout, cin, 3, 3]`, BatchNorm folded.
    pub weight: Param,
    /// `[1, cout]`, BatchNorm folded.
    pub bias: Option<Param>,
    pub cin: usize,
    pub cout: usize,
}

impl Conv3x3 {
    /// The conv at `vars` (with a bias when `bias`), and the BatchNorm at `batch_norm` folded in when given:
    /// w' = w·γ/√(σ²+ε), b' = β + (b − μ)·γ/√(σ²+ε), in float64.
    pub fn new(vars: &Vars, cin: usize, cout: usize, bias: bool, batch_norm: Option<Vars>) -> Result<Conv3x3> {
        let weight = vars.tensor("weight", &[cout, cin, 3, 3])?.data;
        let bias = if bias { Some(vars.tensor("bias", &[cout])?.data) } else { None };
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
                    folded_w[c * cin * 9..(c + 1) * cin * 9].iter_mut().for_each(|v| *v *= scale);
                    let b = bias.as_ref().map_or(0.0, |b| b[c] as f64);
                    folded_b.push(beta[c] as f64 + (b - mean[c] as f64) * scale);
                }
                (Data::F64(folded_w), Some(Data::F64(folded_b)))
            }
        };
        Ok(Conv3x3 {
            path: vars.path().to_string(),
            weight: vars.prepared("weight", Layout::Conv3x3 { cout, cin }, weight),
            bias: bias.map(|b| vars.prepared("bias", Layout::Row, b)),
            cin,
            cout,
        })
    }

    /// `act(conv(x) + b)` into a new image.
    pub fn forward(&self, g: &mut Graph, x: Tensor, resample: Resample, act: Activation) -> Tensor {
        let out = g.image(&self.path, resample.output(x.size()), self.cout);
        self.forward_into(g, x, out, resample, act, false);
        out
    }

    /// `out = act(conv(x) + b)`, or `out += ...` when `accumulate`.
    pub fn forward_into(
        &self,
        g: &mut Graph,
        x: Tensor,
        out: Tensor,
        resample: Resample,
        act: Activation,
        accumulate: bool,
    ) {
        let ImageSize { n, h, w } = x.size();
        let label = g.label(&self.path);
        let weight = g.param(&label, self.weight);
        let bias = self.bias.map(|b| g.param(&label, b));
        let args = Conv3x3Args {
            x: x.view,
            n,
            h,
            w,
            cin: self.cin,
            weight,
            bias,
            out: out.view,
            cout: self.cout,
            stride: if resample == Resample::Down2 { 2 } else { 1 },
            upsample_input: resample == Resample::Up2,
            act,
            accumulate,
        };
        conv3x3(&mut g.b, &label, args);
    }
}
