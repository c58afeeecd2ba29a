//! conv2d against the float64 reference, and the placement helpers the resize and pool tests share.

use raypatch_engine::device::KernelChoice;
use raypatch_engine::device::MatmulKernel;
use raypatch_engine::kernels::conv::{conv2d, pack_conv};
use raypatch_engine::kernels::{conv_output_size, Conv2dArgs, ConvMode, CONV_COOP, CONV_COOP_8};
use raypatch_engine::kernels::{Activation, Window};
use raypatch_engine::plan::{PlanBuilder, View};
use raypatch_engine::tensor::padded_cols;
use raypatch_engine::GpuTensor;
use raypatch_reference::conv as reference;

use crate::common::*;

/// Test data placed as rows `[row_start, row_start + rows)` of a bigger tensor (row_start a multiple of 64,
/// random rows around it), so kernels must index relative to their view. Rows wider than 16 KiB start at 0,
/// so that 64 extra rows cannot push the tensor past the binding size limit.
pub struct Placed {
    tensor: GpuTensor,
    row_start: usize,
    rows: usize,
    /// The whole tensor as uploaded, padding columns included.
    padded: Vec<f32>,
}

impl Placed {
    /// `data` ([rows, cols]) at a random row offset, with `pad` in every padding column: 0 for tensors a kernel
    /// reads or accumulates into (the layout invariant), NaN for outputs, whose padding the kernel must zero.
    pub fn new(rng: &mut Rng, label: &str, data: &[f32], cols: usize, pad: f32) -> Placed {
        let rows = data.len() / cols;
        let row_start = if cols <= 4096 { 64 * rng.range(0, 1) } else { 0 };
        let total = row_start + rows + rng.range(0, 3);
        let ld = padded_cols(cols);
        let mut padded = vec![pad; total * ld];
        for r in 0..total {
            for c in 0..cols {
                padded[r * ld + c] = if (row_start..row_start + rows).contains(&r) {
                    data[(r - row_start) * cols + c]
                } else {
                    rng.uniform(-1.0, 1.0) as f32
                };
            }
        }
        let tensor = gpu().upload(label, total, ld, &padded).expect("upload");
        Placed { tensor: GpuTensor { cols, ..tensor }, row_start, rows, padded }
    }

    /// The placed rows as a view of an external tensor of `plan`.
    pub fn view(&self, plan: &mut PlanBuilder, name: &str) -> View {
        let id = plan.external(name, &self.tensor);
        plan.rows_of(id, self.row_start, self.rows)
    }

    /// Reads the tensor back after a kernel wrote the view: checks that the rows around the view are unchanged
    /// and that the view's padding columns are zero, and returns the view's rows without padding.
    pub fn read_view(&self, what: &str) -> Vec<f32> {
        let (cols, ld) = (self.tensor.cols, padded_cols(self.tensor.cols));
        let all = gpu().read(&GpuTensor { cols: ld, ..self.tensor.clone() }).expect("read");
        let view = self.row_start * ld..(self.row_start + self.rows) * ld;
        for (i, (got, put)) in all.iter().zip(&self.padded).enumerate() {
            if !view.contains(&i) {
                assert!(got.to_bits() == put.to_bits(), "{what}: element {i} outside the view changed");
            } else if i % ld >= cols {
                assert!(*got == 0.0, "{what}: padding element {i} is {got}, not 0");
            }
        }
        all[view].chunks(ld).flat_map(|row| &row[..cols]).copied().collect()
    }
}

/// One convolution case: every option chosen by the caller, data random.
struct Case {
    n: usize,
    h: usize,
    w: usize,
    cin: usize,
    cout: usize,
    window: Window,
    upsample: bool,
    act: Activation,
    bias: bool,
    mode: ConvMode,
}

impl Case {
    /// Runs the case on the GPU with `kernel` as the plan's GEMM kernel and returns (gpu, reference)
    /// outputs and whether `matmul_lanes` ran it.
    fn run(&self, rng: &mut Rng, kernel: MatmulKernel) -> (Vec<f32>, Vec<f64>, bool) {
        self.run_mutated(rng, kernel, None)
    }

    /// [`run`](Self::run), with the tensor kernels' shaders replaced by `mutation` (from, to) of them where given.
    fn run_mutated(
        &self,
        rng: &mut Rng,
        kernel: MatmulKernel,
        mutation: Option<(&str, &str)>,
    ) -> (Vec<f32>, Vec<f64>, bool) {
        let &Case { n, h, w, cin, cout, window, upsample, act, bias, mode } = self;
        let k = window.kernel;
        let (ho, wo) = conv_output_size(h, w, window, upsample).expect("the case's window fits");
        let x = rng.vec_f32(n * h * w * cin, -1.0, 1.0);
        // Kaiming-like scale keeps outputs O(1) for every cin and k.
        let scale = (3.0 / (k * k * cin) as f64).sqrt();
        let weight_data = rng.vec_f32(cout * cin * k * k, -scale, scale);
        let bias_data = bias.then(|| rng.vec_f32(cout, -1.0, 1.0));
        let init = rng.vec_f32(n * ho * wo * cout, -1.0, 1.0);

        let gpu = gpu();
        let xp = Placed::new(rng, "x", &x, cin, 0.0);
        let op = Placed::new(rng, "out", &init, cout, if mode.reads_out() { 0.0 } else { f32::NAN });
        let packed = pack_conv(&weight_data, cout, cin, k);
        let wt = gpu.upload("w", cout, k * k * padded_cols(cin), &packed).expect("upload");
        let bt = bias_data.as_ref().map(|b| gpu.upload("b", 1, cout, b).expect("upload"));

        let mut plan = PlanBuilder::new();
        // Pinned: every case on the family under test, narrow outputs on `Tiled` too.
        plan.kernels = KernelChoice { matmul: kernel, pinned: true, ..gpu.kernels };
        let xv = xp.view(&mut plan, "x");
        let ov = op.view(&mut plan, "out");
        // A model weight, as the models bind it (matmul_lanes keeps its packing).
        let wid = plan.constant("w", &wt);
        let bid = bt.as_ref().map(|b| plan.external("b", b));
        let (weight, bias, upsample_input) = (wid, bid, upsample);
        let args = Conv2dArgs { x: xv, n, h, w, cin, weight, bias, out: ov, cout, window, upsample_input, act, mode };
        conv2d(&mut plan, "conv", args);
        let lanes = plan.op_kernels().any(|k| k == "matmul_lanes.gemm");
        let tiled = plan.op_kernels().any(|k| k.ends_with(".conv_tiled"));
        assert_eq!(tiled, kernel == MatmulKernel::Tiled, "{kernel:?} {self:?}: GPUs' implicit GEMM");
        let coop = plan.op_kernels().any(|k| k.ends_with(".conv_coop"));
        assert_eq!(coop, kernel == MatmulKernel::Coop, "{kernel:?} {self:?}: the tensor kernels' implicit GEMM");
        if let Some((from, to)) = mutation {
            for shader in [&CONV_COOP, &CONV_COOP_8] {
                plan.substitute_shader(shader, mutated(shader, from, to));
            }
        }
        run(plan);
        let got = op.read_view(&format!("{self:?}"));

        let mut expected = to_f64(&init);
        let (mut weight, bias) = (to_f64(&weight_data), bias_data.map(|b| to_f64(&b)));
        let mut x = to_f64(&x);
        if kernel == MatmulKernel::Coop {
            // The tensor kernels round x and w to f16 as they stage them: the float64 product of the rounded
            // operands, within the same f32 summation bound.
            let round = |v: &mut f64| *v = half::f16::from_f64(*v).to_f64();
            x.iter_mut().chain(weight.iter_mut()).for_each(round);
        }
        reference::conv2d(
            &x,
            (n, h, w),
            cin,
            &weight,
            bias.as_deref(),
            cout,
            window,
            upsample,
            act,
            mode,
            &mut expected,
        );
        (got, expected, lanes)
    }

    /// Checks the case on every GEMM kernel the adapter runs (the same data for each); returns whether
    /// `matmul_lanes` ran it.
    fn check(&self, rng: &mut Rng) -> bool {
        self.check_on(rng, &matmul_kernels())
    }

    /// [`check`](Self::check) on `kernels`.
    fn check_on(&self, rng: &mut Rng, kernels: &[MatmulKernel]) -> bool {
        let seed = rng.next_u64();
        let mut lanes = false;
        for &kernel in kernels {
            let (got, expected, ran) = self.run(&mut Rng::new(seed), kernel);
            // f32 accumulation of K = k²·cin products (|x| <= 1, weights scaled so outputs are O(1)): the
            // error grows like sqrt(K)·2^-24; measured at most 2.2e-6 (3×3, cin = 800) on lavapipe, so 1e-5
            // + 1e-6·max|ref| leaves ~4x.
            assert_close(&format!("{kernel:?} {self:?}"), &got, &expected, 1e-5, 1e-6);
            lanes |= ran;
        }
        lanes
    }
}

impl std::fmt::Debug for Case {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Case { n, h, w, cin, cout, window, upsample, act, bias, mode } = self;
        let Window { kernel, stride, padding } = window;
        write!(
            f,
            "conv {n}x{h}x{w}x{cin} -> {cout} k {kernel} stride {stride} padding {padding} upsample {upsample} \
             {act:?} bias {bias} {mode:?}"
        )
    }
}

const ACTS: [Activation; 3] = [Activation::None, Activation::Relu, Activation::LeakyRelu(0.2)];
const MODES: [ConvMode; 3] = [ConvMode::Overwrite, ConvMode::Accumulate, ConvMode::Residual];

/// A 3×3 padding-1 window of `stride` (the SRT and Ray-Patch convs).
fn k3(stride: usize) -> Window {
    Window { kernel: 3, stride, padding: 1 }
}

#[test]
fn conv3x3_random_shapes_every_option() {
    let mut rng = Rng::new(1);
    // 48 cases: each of the 2 (stride) × 2 (upsample) × 2 (bias) × 3 (mode) combinations with each of the
    // 3 activations (the activation and mode cycles are coprime with the rest), on random small shapes (odd
    // sizes, 1-pixel images, channels not multiples of 4).
    for case in 0..48 {
        let c = Case {
            n: rng.range(1, 3),
            h: rng.range(1, 20),
            w: rng.range(1, 20),
            cin: rng.range(1, 40),
            cout: rng.range(1, 40),
            window: k3(1 + case % 2),
            upsample: (case / 2) % 2 == 1,
            bias: (case / 4) % 2 == 1,
            mode: MODES[(case / 8) % 3],
            act: ACTS[case % 3],
        };
        c.check(&mut rng);
    }
}

#[test]
fn conv_any_kernel_stride_padding() {
    let mut rng = Rng::new(5);
    // Kernels 1, 2, 3, 5, 7 with strides 1..3 and paddings 0..3 (more than k/2 too: PyTorch allows it for a
    // conv), every mode, upsampling, on random odd sizes at least as large as the window needs.
    let mut case = 0;
    for kernel in [1, 2, 3, 5, 7] {
        for padding in 0..=3 {
            for stride in 1..=3 {
                let window = Window { kernel, stride, padding };
                let upsample = case % 5 == 4;
                let up = usize::from(upsample);
                // Smallest input the window fits: h_eff + 2·padding >= kernel.
                let least = kernel.saturating_sub(2 * padding).max(1).div_ceil(1 << up);
                let c = Case {
                    n: rng.range(1, 2),
                    h: rng.range(least, least + 12),
                    w: rng.range(least, least + 12),
                    cin: rng.range(1, 19),
                    cout: rng.range(1, 19),
                    window,
                    upsample,
                    bias: case % 2 == 0,
                    mode: MODES[case % 3],
                    act: ACTS[(case / 3) % 3],
                };
                c.check(&mut rng);
                case += 1;
            }
        }
    }
}

#[test]
fn conv_window_exactly_fits() {
    // The padded input exactly the kernel (one output pixel), and a 1-pixel image under a 7×7 pad-3 window.
    let mut rng = Rng::new(6);
    for (h, w, kernel, stride, padding) in [(7, 7, 7, 2, 0), (3, 5, 7, 2, 2), (1, 1, 7, 2, 3), (2, 1, 3, 2, 1)] {
        let window = Window { kernel, stride, padding };
        let (act, mode) = (Activation::Relu, ConvMode::Overwrite);
        Case { n: 2, h, w, cin: 3, cout: 5, window, upsample: false, act, bias: true, mode }.check(&mut rng);
    }
}

#[test]
fn conv_resnet18_layers() {
    // torchvision ResNet-18 at a small input: the 7×7 stride-2 pad-3 stem (no bias, BN folded into a bias), a
    // BasicBlock's 3×3 convs (the second with the residual sum and ReLU), the 1×1 stride-2 downsample, and a
    // strided 3×3 block conv.
    let mut rng = Rng::new(7);
    let relu = Activation::Relu;
    let none = Activation::None;
    let shapes = [
        (45, 61, 3, 64, Window { kernel: 7, stride: 2, padding: 3 }, relu, ConvMode::Overwrite),
        (12, 16, 64, 64, k3(1), relu, ConvMode::Overwrite),
        (12, 16, 64, 64, k3(1), relu, ConvMode::Residual),
        (12, 16, 64, 128, Window { kernel: 1, stride: 2, padding: 0 }, none, ConvMode::Overwrite),
        (12, 16, 64, 128, k3(2), relu, ConvMode::Overwrite),
        (3, 4, 256, 512, Window { kernel: 1, stride: 2, padding: 0 }, none, ConvMode::Overwrite),
        (2, 2, 512, 512, k3(1), relu, ConvMode::Residual),
    ];
    for (h, w, cin, cout, window, act, mode) in shapes {
        Case { n: 2, h, w, cin, cout, window, upsample: false, act, bias: true, mode }.check(&mut rng);
    }
}

#[test]
fn conv3x3_model_channel_counts() {
    let mut rng = Rng::new(2);
    let relu = Activation::Relu;
    let leaky = Activation::LeakyRelu(0.2);
    // (cin, cout, stride, upsample, act): the encoder's first conv (183 -> 96), a strided block, the decoder's
    // upsampling convs, and the largest channel counts the model uses.
    let shapes = [
        (183, 96, 1, false, relu),
        (96, 192, 2, false, relu),
        (128, 64, 1, true, leaky),
        (800, 7, 1, false, Activation::None),
        (5, 800, 2, true, leaky),
    ];
    let mut lanes = 0;
    for (cin, cout, stride, upsample, act) in shapes {
        let (window, mode) = (k3(stride), ConvMode::Overwrite);
        lanes += Case { n: 1, h: 7, w: 9, cin, cout, window, upsample, act, bias: true, mode }.check(&mut rng) as usize;
    }
    // The first three suit matmul_lanes; the 7-channel output and the 5-channel input do not.
    assert_eq!(lanes, if lanes_supported() { 3 } else { 0 }, "convolutions that ran on matmul_lanes");
}

#[test]
fn conv_lanes_random_shapes() {
    // Shapes matmul_lanes takes (at least 24 output channels, input channels in nearly whole blocks of 32,
    // and (24 -> 12) the Ray-Patch decoder's last upsampling conv):
    // kernels 1, 3, 5, strides 1 and 2, paddings 0..2, upsampling, every mode and activation, output
    // channels past a 24-channel tile, pixels past an 8-row tile, several bands of 64 rows.
    let mut rng = Rng::new(8);
    for case in 0..24 {
        let kernel = [1, 3, 5][case % 3];
        let padding = rng.range(0, kernel.min(3) - 1);
        let upsample = case % 4 == 3;
        let least = kernel.saturating_sub(2 * padding).max(1).div_ceil(1 << usize::from(upsample));
        let c = Case {
            n: rng.range(1, 2),
            h: rng.range(least, least + 11),
            w: rng.range(least, least + 11),
            cin: [32, 29, 61, 96, 190, 24][rng.range(0, 5)],
            cout: if case % 7 == 6 { 12 } else { rng.range(24, 80) },
            window: Window { kernel, stride: 1 + case % 2, padding },
            upsample,
            act: ACTS[case % 3],
            bias: case % 5 != 0,
            mode: MODES[(case / 3) % 3],
        };
        let lanes = c.check(&mut rng);
        assert_eq!(lanes, lanes_supported(), "{c:?}: matmul_lanes ran it: {lanes}");
    }
}

fn lanes_supported() -> bool {
    matmul_kernels().contains(&MatmulKernel::Lanes)
}

#[test]
fn conv3x3_many_pixel_tiles() {
    // 9 600 output pixels over 2 images (19 tiles of 512 pixels, the last one partial), upsampled and strided.
    let mut rng = Rng::new(3);
    for (stride, upsample, mode) in [(1, true, ConvMode::Accumulate), (2, false, ConvMode::Residual)] {
        let (h, w) = if upsample { (30, 40) } else { (120, 160) };
        let act = Activation::LeakyRelu(0.2);
        Case { n: 2, h, w, cin: 6, cout: 13, window: k3(stride), upsample, act, bias: true, mode }.check(&mut rng);
    }
}

#[test]
fn conv3x3_grid_spills_into_y() {
    // More than 65535 workgroups (channel tiles of 8), so plan::grid spills into y: one pixel, 524 296 channels.
    let mut rng = Rng::new(4);
    let cout: usize = 524_296;
    assert!(cout.div_ceil(8) > 65535, "the case no longer spills the grid");
    Case {
        n: 1,
        h: 1,
        w: 1,
        cin: 1,
        cout,
        window: k3(1),
        upsample: false,
        act: Activation::Relu,
        bias: true,
        mode: ConvMode::Overwrite,
    }
    .check(&mut rng);
}

/// On `Tiled`, a convolution whose output has too few 128x128 tiles to fill a GPU splits its weight row (K) among
/// workgroups and adds the ranges up in `conv_reduce`, which finishes them (every mode: the random shapes and
/// model channel counts above run split on `Tiled`); one whose tiles are enough runs in one dispatch.
#[test]
fn conv_tiled_splits_k_when_tiles_are_few() {
    for (h, w, cin, cout, splits) in [(30, 40, 192, 384, true), (120, 160, 3, 96, false)] {
        let mut plan = PlanBuilder::new();
        plan.kernels = KernelChoice { matmul: MatmulKernel::Tiled, ..gpu().kernels };
        let x = plan.transient("x", h * w, cin);
        let weight = plan.transient("w", cout, 9 * padded_cols(cin));
        let out = plan.transient("out", h * w, cout);
        let (x, out) = (plan.all(x), plan.all(out));
        let (act, mode, window) = (Activation::Relu, ConvMode::Overwrite, k3(1));
        let args =
            Conv2dArgs { x, n: 1, h, w, cin, weight, bias: None, out, cout, window, upsample_input: false, act, mode };
        conv2d(&mut plan, "conv", args);
        assert_eq!(plan.op_kernels().any(|k| k.ends_with(".conv_reduce")), splits, "{h}x{w}, {cin} -> {cout}");
    }
}

/// On the GPU profile (not pinned), `Tiled` runs convolutions of 64 output channels or more on `conv_tiled`;
/// narrower ones over many pixels (the Ray-Patch decoders' last feature and image convolutions at 480x640) on
/// `Rows`, whose 8-channel tiles waste little where a 128-channel tile would waste most of its work; narrow ones
/// over few pixels stay on `conv_tiled`, whose K split keeps them from being a few long chains.
#[test]
fn tiled_profile_leaves_narrow_convolutions_to_rows() {
    let gpu_profile = KernelChoice { matmul: MatmulKernel::Tiled, pinned: false, ..gpu().kernels };
    let entry = |(h, w): (usize, usize), cout: usize| {
        let mut plan = PlanBuilder::new();
        plan.kernels = gpu_profile;
        let cin = 32;
        let x = plan.transient("x", h * w, cin);
        let weight = plan.transient("w", cout, 9 * padded_cols(cin));
        let out = plan.transient("out", 4 * h * w, cout);
        let (x, out) = (plan.all(x), plan.all(out));
        let (act, mode, window) = (Activation::None, ConvMode::Overwrite, k3(1));
        let args =
            Conv2dArgs { x, n: 1, h, w, cin, weight, bias: None, out, cout, window, upsample_input: true, act, mode };
        conv2d(&mut plan, "conv", args);
        let first = plan.op_kernels().next().expect("one op");
        first
    };
    // Inputs upsampled 2x: 240x320 and 30x40 give 480x640 and 60x80 outputs.
    assert_eq!(entry((240, 320), 64), "conv.conv_tiled");
    for cout in [32, 16, 3, 1] {
        assert_eq!(entry((240, 320), cout), "conv.conv2d", "{cout} output channels at 480x640");
        assert_eq!(entry((30, 40), cout), "conv.conv_tiled", "{cout} output channels at 60x80");
    }
}

/// The tensor kernels' convolution (`conv_coop`, an implicit GEMM on f16 cooperative matrices), where the device has
/// them (`.ci/coop.sh`): against the float64 convolution of the f16-rounded input and weights, within f32 summation's
/// bound; random 3x3 shapes with every option, other windows, strides and paddings, the ResNet stem, upsampling, and
/// a deep K whose few tiles split it.
#[test]
fn conv_coop() {
    if !coop_runs() {
        return;
    }
    let mut rng = Rng::new(11);
    let coop = [MatmulKernel::Coop];
    for case in 0..24 {
        let kernel = [3, 1, 5, 7][case % 4];
        let padding = rng.range(0, kernel / 2);
        let c = Case {
            n: rng.range(1, 3),
            h: rng.range(kernel, 24),
            w: rng.range(kernel, 24),
            cin: rng.range(1, 70),
            cout: rng.range(1, 70),
            window: Window { kernel, stride: 1 + case % 2, padding },
            upsample: (case / 2) % 2 == 1,
            bias: (case / 4) % 2 == 1,
            mode: MODES[(case / 8) % 3],
            act: ACTS[case % 3],
        };
        c.check_on(&mut rng, &coop);
    }
    let (relu, residual) = (Activation::Relu, ConvMode::Residual);
    let stem = Window { kernel: 7, stride: 2, padding: 3 };
    Case {
        n: 1,
        h: 45,
        w: 61,
        cin: 3,
        cout: 64,
        window: stem,
        upsample: false,
        act: relu,
        bias: true,
        mode: ConvMode::Overwrite,
    }
    .check_on(&mut rng, &coop);
    Case {
        n: 1,
        h: 6,
        w: 5,
        cin: 300,
        cout: 20,
        window: k3(1),
        upsample: false,
        act: relu,
        bias: true,
        mode: residual,
    }
    .check_on(&mut rng, &coop);
}

/// The mutation check of `conv_coop`: a wrong fragment index, a skipped K step or a skipped output block must fail
/// its check.
#[test]
fn conv_coop_mutations_fail() {
    if !coop_runs() {
        return;
    }
    let mutations = [
        ("let a1_at = a_base + (sr + CT) * COOP_LD + kk;", "let a1_at = a_base + sr * COOP_LD + kk;"),
        ("if (step + 1u < t.steps) {", "if (step + 2u < t.steps) {"),
        ("coop_emit(t, sr, sc + CT, at, lane);", ""),
    ];
    for (from, to) in mutations {
        let case = Case {
            n: 1,
            h: 9,
            w: 11,
            cin: 40,
            cout: 36,
            window: k3(1),
            upsample: false,
            act: Activation::None,
            bias: true,
            mode: ConvMode::Overwrite,
        };
        fails_on_values(&format!("conv_coop with {from:?} replaced by {to:?}"), || {
            let (got, expected, _) = case.run_mutated(&mut Rng::new(3), MatmulKernel::Coop, Some((from, to)));
            assert_close("conv_coop mutated", &got, &expected, 1e-5, 1e-6);
        });
    }
}
