//! Speed of the convolution on the models' shapes, for comparing kernel changes (ignored; run with
//! `cargo test --release --test kernels conv_speed -- --ignored --nocapture`, `CONV_SPEED=<name part>` to
//! pick shapes). On a shared machine wall times vary 2× with the load; the process CPU time per conv
//! (lavapipe runs the shader on the process's threads) varies by a few percent, so compare that.

use raypatch_engine::kernels::conv::conv2d;
use raypatch_engine::kernels::{conv_output_size, Conv2dArgs, ConvMode};
use raypatch_engine::kernels::{Activation, Window};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::padded_cols;

use crate::common::*;

/// Convs per plan, and profiled runs of the plan.
const CONVS: usize = 5;
const RUNS: usize = 4;

#[test]
#[ignore]
fn conv_speed() {
    let gpu = gpu();
    // (name, h, w, cin, cout, window, upsample): the Ray-Patch decoder's upsampling convs and the SRT
    // encoder's at 120x160 inputs, ResNet-18's stem and a downsample.
    let shapes = [
        ("dec 128->64 up 30x40", 30, 40, 128, 64, Window::new(3, 1, 1), true),
        ("dec 64->32 up 60x80", 60, 80, 64, 32, Window::new(3, 1, 1), true),
        ("enc 183->96 s1 60x80", 60, 80, 183, 96, Window::new(3, 1, 1), false),
        ("enc 96->192 s2 60x80", 60, 80, 96, 192, Window::new(3, 2, 1), false),
        ("stem 3->64 k7 s2 120x160", 120, 160, 3, 64, Window::new(7, 2, 3), false),
        ("down 64->128 k1 s2 30x40", 30, 40, 64, 128, Window::new(1, 2, 0), false),
    ];
    let filter = std::env::var("CONV_SPEED").unwrap_or_default();
    for (name, h, w, cin, cout, window, upsample_input) in shapes {
        if !name.contains(filter.as_str()) {
            continue;
        }
        let k = window.kernel;
        let (ho, wo) = conv_output_size(h, w, window, upsample_input).expect("fits");
        let mut plan = PlanBuilder::new();
        let x = plan.input("x", h * w, cin);
        let weight = plan.input("w", cout, k * k * padded_cols(cin));
        let bias = Some(plan.input("b", 1, cout));
        let out = plan.output("out", ho * wo, cout);
        let (x, out) = (plan.all(x), plan.all(out));
        let (act, mode) = (Activation::Relu, ConvMode::Overwrite);
        for _ in 0..CONVS {
            let args = Conv2dArgs { x, n: 1, h, w, cin, weight, bias, out, cout, window, upsample_input, act, mode };
            conv2d(&mut plan, "conv", args);
        }
        let plan = plan.build(gpu).expect("build");
        plan.profile(gpu).expect("warm-up");
        let cpu0 = cpu_seconds();
        let mut times: Vec<f64> = Vec::new();
        for _ in 0..RUNS {
            times.extend(plan.profile(gpu).expect("profile").iter().map(|(_, t)| t.as_secs_f64() * 1e3));
        }
        let cpu = (cpu_seconds() - cpu0) / times.len() as f64 * 1e3;
        times.sort_by(f64::total_cmp);
        let giga = (ho * wo * cout * k * k * cin) as f64 / 1e9;
        eprintln!(
            "SPEED {name}: {cpu:.1} ms CPU per conv ({:.2} GMAC per CPU second); wall min {:.1} ms, median {:.1} ms",
            giga / cpu * 1e3,
            times[0],
            times[times.len() / 2],
        );
    }
}

/// User + system CPU time of this process, all threads (`/proc/self/stat`, in clock ticks of 10 ms).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat");
    let fields: Vec<&str> = stat.rsplit(')').next().expect("stat").split_whitespace().collect();
    let ticks = |i: usize| fields[i].parse::<f64>().expect("clock ticks");
    (ticks(11) + ticks(12)) / 100.0
}
