//! torchvision's ResNet-18 as the official DeFiNe encoder uses it (`src/resnet.py` `ResNetSkip`: no avgpool,
//! no fc, the four stages' outputs returned): 7×7 stride-2 stem → BatchNorm → ReLU → 3×3 stride-2 max pool,
//! then four stages of two `BasicBlock`s, widths w, 2w, 4w, 8w (torchvision: w = 64). BatchNorms are folded
//! into the convs that precede them.

use super::{Conv2d, ConvSpec, MaxPool2d, Vars};
use crate::error::Result;
use crate::graph::{Graph, Tensor};
use crate::kernels::Activation;
use crate::kernels::ConvMode;

/// torchvision `BasicBlock`: relu(bn2(conv2(relu(bn1(conv1(x))))) + identity), the identity being
/// `downsample(x)` (1×1 stride-2 conv + BN) where the block changes the width or size.
pub struct BasicBlock {
    pub conv1: Conv2d,
    pub conv2: Conv2d,
    pub downsample: Option<Conv2d>,
}

impl BasicBlock {
    fn new(vars: &Vars, cin: usize, cout: usize, stride: usize) -> Result<BasicBlock> {
        let conv =
            |name: &str, bn: &str, spec: ConvSpec| Conv2d::new(&vars.pp(name), spec.no_bias(), Some(vars.pp(bn)));
        Ok(BasicBlock {
            conv1: conv("conv1", "bn1", ConvSpec::new(cin, cout, 3, stride, 1))?,
            conv2: conv("conv2", "bn2", ConvSpec::new(cout, cout, 3, 1, 1))?,
            downsample: if stride != 1 || cin != cout {
                Some(conv("downsample.0", "downsample.1", ConvSpec::new(cin, cout, 1, stride, 0))?)
            } else {
                None
            },
        })
    }

    /// The block on `x`. Without a downsample the sum is formed in `x` itself (its last reader is this
    /// block's first conv, which has run by then).
    fn forward(&self, g: &mut Graph, x: Tensor) -> Tensor {
        let h = self.conv1.forward(g, x, Activation::Relu);
        let identity = match &self.downsample {
            Some(downsample) => downsample.forward(g, x, Activation::None),
            None => x,
        };
        self.conv2.forward_into(g, h, identity, Activation::Relu, ConvMode::Residual);
        identity
    }
}

/// `ResNetSkip(BasicBlock, [2, 2, 2, 2])`.
pub struct ResNet18 {
    pub conv1: Conv2d,
    pub maxpool: MaxPool2d,
    /// `layer1..layer4`, two blocks each.
    pub layers: Vec<[BasicBlock; 2]>,
}

impl ResNet18 {
    /// The ResNet at `vars` with stem width `width` (torchvision: 64).
    pub fn new(vars: &Vars, width: usize) -> Result<ResNet18> {
        let mut layers = Vec::with_capacity(4);
        let mut cin = width;
        for i in 0..4 {
            let (cout, stride) = (width << i, if i == 0 { 1 } else { 2 });
            let layer = vars.pp(format!("layer{}", i + 1));
            layers.push([
                BasicBlock::new(&layer.pp(0), cin, cout, stride)?,
                BasicBlock::new(&layer.pp(1), cout, cout, 1)?,
            ]);
            cin = cout;
        }
        Ok(ResNet18 {
            conv1: Conv2d::new(&vars.pp("conv1"), ConvSpec::new(3, width, 7, 2, 3).no_bias(), Some(vars.pp("bn1")))?,
            maxpool: MaxPool2d::new(vars.pp("maxpool").path(), 3, 2, 1),
            layers,
        })
    }

    /// The four stages' outputs `[x_1, x_2, x_3, x_4]` of NHWC images `x`.
    pub fn forward(&self, g: &mut Graph, x: Tensor) -> [Tensor; 4] {
        let x = self.conv1.forward(g, x, Activation::Relu);
        let mut x = self.maxpool.forward(g, x);
        let mut outputs = Vec::with_capacity(4);
        for blocks in &self.layers {
            x = blocks.iter().fold(x, |x, block| block.forward(g, x));
            outputs.push(x);
        }
        outputs.try_into().unwrap_or_else(|_| unreachable!("four stages"))
    }
}
