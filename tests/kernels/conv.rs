//! conv3x3 against the float64 reference, and the placement helpers the resize tests share.

use raypatch_engine::kernels::conv::{conv3x3, pack_conv3x3, Conv3x3Args};
use raypatch_engine::kernels::Activation;
use raypatch_engine::plan::{PlanBuilder, View};
use raypatch_engine::reference::conv as reference;
use raypatch_engine::tensor::padded_cols;
use raypatch_engine::GpuTensor;

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
    stride: usize,
    upsample: bool,
    act: Activation,
    bias: bool,
    accumulate: bool,
}

impl Case {
    /// Runs the case on the GPU and returns (gpu, reference) outputs.
    fn run(&self, rng: &mut Rng) -> (Vec<f32>, Vec<f64>) {
        let &Case { n, h, w, cin, cout, stride, upsample, act, bias, accumulate } = self;
        let up = usize::from(upsample);
        let (ho, wo) = (((h << up) - 1) / stride + 1, ((w << up) - 1) / stride + 1);
        let x = rng.vec_f32(n * h * w * cin, -1.0, 1.0);
        // Kaiming-like scale keeps outputs O(1) for every cin.
        let scale = (3.0 / (9 * cin) as f64).sqrt();
        let weight_data = rng.vec_f32(cout * cin * 9, -scale, scale);
        let bias_data = bias.then(|| rng.vec_f32(cout, -1.0, 1.0));
        let init = rng.vec_f32(n * ho * wo * cout, -1.0, 1.0);

        let gpu = gpu();
        let xp = Placed::new(rng, "x", &x, cin, 0.0);
        let op = Placed::new(rng, "out", &init, cout, if accumulate { 0.0 } else { f32::NAN });
        let wt = gpu.upload("w", cout, 9 * padded_cols(cin), &pack_conv3x3(&weight_data, cout, cin)).expect("upload");
        let bt = bias_data.as_ref().map(|b| gpu.upload("b", 1, cout, b).expect("upload"));

        let mut plan = PlanBuilder::new();
        let xv = xp.view(&mut plan, "x");
        let ov = op.view(&mut plan, "out");
        let wid = plan.external("w", &wt);
        let bid = bt.as_ref().map(|b| plan.external("b", b));
        let (weight, bias, upsample_input) = (wid, bid, upsample);
        let args =
            Conv3x3Args { x: xv, n, h, w, cin, weight, bias, out: ov, cout, stride, upsample_input, act, accumulate };
        conv3x3(&mut plan, "conv", args);
        run(plan);
        let got = op.read_view(&format!("{self:?}"));

        let residual = accumulate.then(|| to_f64(&init));
        let expected = reference::conv3x3(
            &to_f64(&x),
            n,
            h,
            w,
            cin,
            &to_f64(&weight_data),
            bias_data.map(|b| to_f64(&b)).as_deref(),
            cout,
            stride,
            upsample,
            act,
            residual.as_deref(),
        );
        (got, expected)
    }

    fn check(&self, rng: &mut Rng) {
        let (got, expected) = self.run(rng);
        // f32 accumulation of K = 9·cin products (|x| <= 1, weights scaled so outputs are O(1)): the error grows
        // like sqrt(K)·2^-24; measured at most 2.2e-6 (cin = 800) on lavapipe, so 1e-5 + 1e-6·max|ref| leaves ~4x.
        assert_close(&format!("{self:?}"), &got, &expected, 1e-5, 1e-6);
    }
}

impl std::fmt::Debug for Case {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Case { n, h, w, cin, cout, stride, upsample, act, bias, accumulate } = self;
        write!(f, "conv {n}x{h}x{w}x{cin} -> {cout} stride {stride} upsample {upsample} {act:?} bias {bias} accumulate {accumulate}")
    }
}

const ACTS: [Activation; 3] = [Activation::None, Activation::Relu, Activation::LeakyRelu(0.2)];

#[test]
fn conv3x3_random_shapes_every_option() {
    let mut rng = Rng::new(1);
    // 48 cases: each of the 2 (stride) × 2 (upsample) × 2 (bias) × 2 (accumulate) combinations with each of the
    // 3 activations, on random small shapes (odd sizes, 1-pixel images, channels not multiples of 4).
    for case in 0..48 {
        let c = Case {
            n: rng.range(1, 3),
            h: rng.range(1, 20),
            w: rng.range(1, 20),
            cin: rng.range(1, 40),
            cout: rng.range(1, 40),
            stride: 1 + case % 2,
            upsample: (case / 2) % 2 == 1,
            bias: (case / 4) % 2 == 1,
            accumulate: (case / 8) % 2 == 1,
            act: ACTS[case % 3],
        };
        c.check(&mut rng);
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
    for (cin, cout, stride, upsample, act) in shapes {
        Case { n: 1, h: 7, w: 9, cin, cout, stride, upsample, act, bias: true, accumulate: false }.check(&mut rng);
    }
}

#[test]
fn conv3x3_many_pixel_tiles() {
    // 9 600 output pixels over 2 images (19 tiles of 512 pixels, the last one partial), upsampled and strided.
    let mut rng = Rng::new(3);
    for (stride, upsample) in [(1, true), (2, false)] {
        let (h, w) = if upsample { (30, 40) } else { (120, 160) };
        let act = Activation::LeakyRelu(0.2);
        Case { n: 2, h, w, cin: 6, cout: 13, stride, upsample, act, bias: true, accumulate: true }.check(&mut rng);
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
        stride: 1,
        upsample: false,
        act: Activation::Relu,
        bias: true,
        accumulate: false,
    }
    .check(&mut rng);
}
