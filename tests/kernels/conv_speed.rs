//! Timing of the convolution on model shapes (ignored: run with --ignored --nocapture).

use raypatch_engine::kernels::conv::{conv2d, conv_output_size, Conv2dArgs, ConvMode};
use raypatch_engine::kernels::{Activation, Window};
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::tensor::padded_cols;

use crate::common::*;

#[test]
#[ignore]
fn conv_speed() {
    let gpu = gpu();
    // (name, h, w, cin, cout, k, stride, pad, upsample)
    let shapes = [
        ("dec 128->64 up 30x40", 30, 40, 128, 64, 3, 1, 1, true),
        ("dec 64->32 up 60x80", 60, 80, 64, 32, 3, 1, 1, true),
        ("enc 183->96 s1 60x80", 60, 80, 183, 96, 3, 1, 1, false),
        ("enc 96->192 s2 60x80", 60, 80, 96, 192, 3, 2, 1, false),
        ("stem 3->64 k7 s2 120x160", 120, 160, 3, 64, 7, 2, 3, false),
        ("down 64->128 k1 s2 30x40", 30, 40, 64, 128, 1, 2, 0, false),
    ];
    let filter = std::env::var("CONV_SPEED").unwrap_or_default();
    for (name, h, w, cin, cout, k, stride, pad, upsample) in shapes {
        if !name.contains(filter.as_str()) {
            continue;
        }
        let window = Window::new(k, stride, pad);
        let (ho, wo) = conv_output_size(h, w, window, upsample).unwrap();
        let mut plan = PlanBuilder::new();
        let x = plan.input("x", h * w, cin);
        let weight = plan.input("w", cout, k * k * padded_cols(cin));
        let bias = Some(plan.input("b", 1, cout));
        let out = plan.output("out", ho * wo, cout);
        let (x, out) = (plan.all(x), plan.all(out));
        let (act, mode) = (Activation::Relu, ConvMode::Overwrite);
        for _ in 0..5 {
            let args =
                Conv2dArgs { x, n: 1, h, w, cin, weight, bias, out, cout, window, upsample_input: upsample, act, mode };
            conv2d(&mut plan, "conv", args);
        }
        let plan = plan.build(gpu).expect("build");
        plan.profile(gpu).expect("warm");
        let cpu0 = cpu_seconds();
        let mut times: Vec<f64> = Vec::new();
        for _ in 0..4 {
            times.extend(plan.profile(gpu).expect("profile").iter().map(|(_, t)| t.as_secs_f64() * 1e3));
        }
        let cpu = (cpu_seconds() - cpu0) / times.len() as f64 * 1e3;
        eprintln!("CPU {name}: {cpu:.2} ms of process CPU time per conv");
        times.sort_by(f64::total_cmp);
        let macs = (ho * wo * cout * k * k * cin) as f64;
        eprintln!(
            "SPEED {name}: min {:.2} ms median {:.2} ms ({:.2} GMAC/s at min)",
            times[0],
            times[times.len() / 2],
            macs / times[0] / 1e6
        );
    }
}

/// User + system CPU time of this process (all threads), from /proc/self/stat (clock ticks of 10 ms).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat");
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap().split_whitespace().collect();
    let ticks: f64 = fields[11].parse::<f64>().unwrap() + fields[12].parse::<f64>().unwrap();
    ticks / 100.0
}
