//! Square K×K convolutions on NHWC images (`shaders/conv.wgsl`), any stride and zero padding: the SRT
//! encoder's conv blocks (3×3, stride 1 and 2), the Ray-Patch decoder's upsample-then-conv layers, and
//! ResNet's 7×7 stem, 3×3 blocks and 1×1 downsamples, with BatchNorm folded into the weight and bias by the
//! model loader, the activation fused, and a residual sum fused before it. On GPUs (`MatmulKernel::Tiled`)
//! they run as an implicit GEMM in workgroup-memory tiles (`conv.wgsl`'s `conv_tiled`); on CPU adapters most
//! run on `matmul_lanes` (`kernels::matmul::gemm_lanes`, an implicit GEMM over packed textures); the rest on
//! `conv.wgsl`'s register-blocked `conv2d`.

use crate::device::{conv_variant, MatmulKernel};
use crate::kernels::matmul::{gemm_lanes, lanes_fit, split_k, split_k_in_steps, LANES_COLS, TILED_TILE};
use crate::kernels::pack::Packing;
use crate::kernels::{conv_output_size, Conv2dArgs, Window, CONV, CONV_COOP, CONV_COOP_8};
use crate::plan::{grid, Access, Op, PlanBuilder};
use crate::tensor::padded_cols;

/// Output pixels per invocation, 64 apart in the flattened n*ho*wo order (`PX` in the shader).
const PIXELS_PER_INVOCATION: usize = 8;
/// Vec4s of output channels per invocation (`CV` in the shader).
const COUT_VEC4S_PER_INVOCATION: usize = 2;

/// Repacks a PyTorch conv weight [cout, cin, k, k] (row-major) into the kernel's layout, returned as a
/// row-major [cout, k*k * padded_cols(cin)] matrix: for each output channel, the k*k taps (ky, kx row-major),
/// each a zero-padded run of cin input channels. Upload it with
/// `Gpu::upload(label, cout, k * k * padded_cols(cin), &packed)`.
pub fn pack_conv(weight: &[f32], cout: usize, cin: usize, k: usize) -> Vec<f32> {
    let taps = k * k;
    assert_eq!(weight.len(), cout * cin * taps, "pack_conv: weight has {} values, not cout*cin*k*k", weight.len());
    let ld = padded_cols(cin);
    let mut packed = vec![0.0; cout * taps * ld];
    for co in 0..cout {
        for ci in 0..cin {
            for tap in 0..taps {
                packed[(co * taps + tap) * ld + ci] = weight[(co * cin + ci) * taps + tap];
            }
        }
    }
    packed
}

params! {
    /// The uniform of `shaders/conv.wgsl`.
    ConvParams {
        h: u32,
        w: u32,
        /// ld(cin) / 4: vec4s per row of x and per tap of w.
        cin4: u32,
        cout: u32,
        /// ld(cout) / 4: vec4s per row of out.
        cout4: u32,
        ho: u32,
        wo: u32,
        /// The window: K × K taps, stride, zero padding.
        k: u32,
        stride: u32,
        pad: u32,
        /// 1 when the input is upsampled 2× (nearest) before the convolution, else 0.
        up: u32,
        /// Activation code and slope ([`Activation::params`](crate::kernels::Activation::params)).
        act: u32,
        slope: f32,
        has_bias: u32,
        /// [`ConvMode::code`](crate::kernels::ConvMode::code).
        mode: u32,
        /// n*ho*wo.
        npix: u32,
        /// Channel tiles, the fastest-varying part of the group index (per entry point: see the shader).
        cout_tiles: u32,
        /// Pixel tiles (per entry point: see the shader).
        pixel_tiles: u32,
        /// `conv_tiled`: the weight row (K) cut into `splits` ranges of `k_split4` vec4s, one per workgroup, when
        /// the output's tiles are too few to fill a GPU (`kernels::matmul::split_k`); `conv_reduce` adds them.
        splits: u32,
        k_split4: u32,
    }
}

/// Whether this convolution suits `matmul_lanes`: its operands fit in textures and at least a third of the
/// kernel's work is useful. It computes whole tiles of `LANES_COLS` (32) output
/// channels and pads each tap's input channels to whole blocks of 8 texels (32 channels); `conv.wgsl` runs 3-8x slower
/// on llvmpipe, so the Ray-Patch decoder's 3-channel RGB convs and ResNet's 3-channel stem stay there.
fn lanes_suit(plan: &PlanBuilder, args: &Conv2dArgs) -> bool {
    // A tap's input channels as vec4s, and as the texels matmul_lanes reads for them.
    let cin4 = padded_cols(args.cin) / 4;
    let useful_cin = cin4 as f64 / Packing::IMAGE.texels_per_row(args.cin) as f64;
    let useful_cout = args.cout as f64 / (args.cout.div_ceil(LANES_COLS) * LANES_COLS) as f64;
    useful_cin * useful_cout >= 1.0 / 3.0 && lanes_fit(plan, args)
}

/// K×K convolution with zero padding and any stride, NHWC: x is [n*h*w, cin]. With `upsample_input` the
/// input is first upsampled 2× nearest (the conv sees a 2h×2w image; fused: x is read at (y/2, x/2), never
/// materialised). Output [n*ho*wo, cout] with ho = (h_eff + 2·padding − k) / stride + 1 (h_eff = h or 2h),
/// written as `mode` says: act(conv + bias), out + act(conv + bias), or act(out + conv + bias).
///
/// `weight` is [`pack_conv`]'s `[cout, k*k * padded_cols(cin)]` matrix, `bias` a `[1, cout]` tensor. `act`
/// is any [`Activation`](crate::kernels::Activation). The padding columns of `out` are written with zeros (or
/// stay zero when reading `out`). `out` must not overlap `x`. Records `n·ho·wo·cout·k²·cin` multiply-adds.
pub fn conv2d(plan: &mut PlanBuilder, label: &str, args: Conv2dArgs) {
    let Conv2dArgs { x, n, h, w, cin, weight, bias, out, cout, window, upsample_input, act, mode } = args;
    if plan.failed() {
        return; // a tensor is too large to index: the plan will not be built
    }
    let Window { kernel, stride, padding } = window;
    assert!(n > 0 && h > 0 && w > 0 && cin > 0 && cout > 0, "{label}: empty convolution");
    assert!(kernel > 0 && stride > 0, "{label}: kernel {kernel} and stride {stride} must be at least 1");
    assert_eq!(x.rows, n * h * w, "{label}: x has {} rows, not n*h*w = {n}*{h}*{w}", x.rows);
    assert_eq!(plan.cols(x.id), cin, "{label}: x has {} columns, not cin = {cin}", plan.cols(x.id));
    let taps = kernel * kernel;
    let (wrows, wcols) = (plan.rows(weight), plan.cols(weight));
    assert!(
        wrows == cout && wcols == taps * padded_cols(cin),
        "{label}: weight is [{wrows}, {wcols}], not the packed [cout, k*k*ld(cin)] = [{cout}, {}]",
        taps * padded_cols(cin)
    );
    if let Some(b) = bias {
        let (brows, bcols) = (plan.rows(b), plan.cols(b));
        assert!(brows == 1 && bcols == cout, "{label}: bias is [{brows}, {bcols}], not [1, {cout}]");
    }
    let Some((ho, wo)) = conv_output_size(h, w, window, upsample_input) else {
        panic!("{label}: a {kernel}x{kernel} window with padding {padding} does not fit a {h}x{w} image (upsampled: {upsample_input})");
    };
    let npix = n * ho * wo;
    assert_eq!(out.rows, npix, "{label}: out has {} rows, not n*ho*wo = {n}*{ho}*{wo}", out.rows);
    assert_eq!(plan.cols(out.id), cout, "{label}: out has {} columns, not cout = {cout}", plan.cols(out.id));

    let cout4 = padded_cols(cout) / 4;
    let rows_grid = (cout4.div_ceil(COUT_VEC4S_PER_INVOCATION), npix.div_ceil(64 * PIXELS_PER_INVOCATION));
    let variant = conv_variant(&plan.kernels, cout, rows_grid.0 * rows_grid.1, || lanes_suit(plan, &args));
    let coop = plan.kernels.coop.filter(|_| variant == MatmulKernel::Coop);
    let (shader, entry, cout_tiles, pixel_tiles) = match (variant, coop) {
        (MatmulKernel::Lanes, _) => return gemm_lanes(plan, label, args),
        (MatmulKernel::Tiled, _) => (&CONV, "conv_tiled", cout4.div_ceil(TILED_TILE / 4), npix.div_ceil(TILED_TILE)),
        (MatmulKernel::Coop, Some(shape)) => {
            let shader = if shape.tile == 8 { &CONV_COOP_8 } else { &CONV_COOP };
            let tiling = shape.tiling(npix);
            (shader, "conv_coop", cout.div_ceil(shape.tile_cols(tiling)), npix.div_ceil(shape.tile_rows(tiling)))
        }
        (MatmulKernel::Coop, None) => panic!("{label}: the tensor kernels run only where the device has them"),
        (MatmulKernel::Rows, _) => (&CONV, "conv2d", rows_grid.0, rows_grid.1),
    };
    // Split K where the output's tiles are too few to fill a GPU (an encoder's 30x40 layers: 20 tiles).
    let k4 = taps * padded_cols(cin) / 4;
    let (splits, k_split4) = match (entry, coop) {
        ("conv_tiled", _) => split_k(pixel_tiles * cout_tiles, k4),
        (_, Some(shape)) => split_k_in_steps(pixel_tiles * cout_tiles, k4, shape.tiling(npix).bk as usize / 4),
        _ => (1, k4),
    };
    let (act_code, slope) = act.params();
    let params = ConvParams {
        h: h as u32,
        w: w as u32,
        cin4: (padded_cols(cin) / 4) as u32,
        cout: cout as u32,
        cout4: cout4 as u32,
        ho: ho as u32,
        wo: wo as u32,
        k: kernel as u32,
        stride: stride as u32,
        pad: padding as u32,
        up: u32::from(upsample_input),
        act: act_code,
        slope,
        has_bias: bias.is_some() as u32,
        mode: mode.code(),
        npix: npix as u32,
        cout_tiles: cout_tiles as u32,
        pixel_tiles: pixel_tiles as u32,
        splits: splits as u32,
        k_split4: k_split4 as u32,
    };
    let weight_view = plan.all(weight);
    let bias_view = bias.map_or(weight_view, |b| plan.all(b));
    let out_access = if mode.reads_out() { Access::ReadWrite } else { Access::Write };
    let multiply_adds = (npix as u64) * (cout as u64) * (taps as u64) * (cin as u64);
    // Split K: each range's raw sums into the partials, then one pass adding them up and finishing into out.
    let (written, op_label) = if splits == 1 {
        ((out, out_access), label.to_string())
    } else {
        let partials = plan.transient(&format!("{label}.partials"), splits * npix, cout);
        ((plan.all(partials), Access::Write), format!("{label}.split"))
    };
    plan.push(Op {
        label: op_label,
        shader,
        entry,
        params: params.words(),
        bindings: vec![(x, Access::Read), (weight_view, Access::Read), (bias_view, Access::Read), written],
        textures: Vec::new(),
        workgroups: grid(pixel_tiles * cout_tiles * splits),
        constants: coop.map_or(Vec::new(), |shape| shape.constants(shape.tiling(npix))),
        multiply_adds,
    });
    if splits > 1 {
        plan.push(Op {
            label: format!("{label}.reduce"),
            shader,
            entry: "conv_reduce",
            params: params.words(),
            bindings: vec![
                (written.0, Access::Read),
                (weight_view, Access::Read),
                (bias_view, Access::Read),
                (out, out_access),
            ],
            textures: Vec::new(),
            workgroups: grid((npix * cout4).div_ceil(64)),
            constants: Vec::new(),
            multiply_adds: 0,
        });
    }
}
