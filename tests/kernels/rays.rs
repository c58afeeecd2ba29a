//! A pinhole camera's rays made on the GPU against the host's (`raypatch_model::pinhole`): bit-equal, for
//! random cameras of both ray kinds (views of both kinds in one dispatch: each view's terms carry its kind), with
//! each row's padding zeroed. The host's are within one float32
//! rounding of the float64 rays (tested beside them), so this is what makes a render from a camera's pose on
//! the GPU see the rays the host gives for it.

use raypatch_engine::kernels::rays::{pinhole_rays, PinholeRaysArgs};
use raypatch_engine::plan::PlanBuilder;
use raypatch_model::pinhole::{Intrinsics, PinholeRays, TERM_FLOATS};
use raypatch_model::RayKind;

use crate::common::*;

const SENTINEL: f32 = -7.5;

/// A random rotation (columns), from Gram-Schmidt on normal vectors, perturbed by up to 1e-5 (poses stored
/// as text are orthonormal only to their digits).
fn rotation(rng: &mut Rng) -> [[f64; 3]; 3] {
    let mut v = || [rng.normal(), rng.normal(), rng.normal()];
    let (a, b) = (v(), v());
    let dot = |p: [f64; 3], q: [f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let unit = |p: [f64; 3]| p.map(|c| c / dot(p, p).sqrt());
    let x = unit(a);
    let y = unit(std::array::from_fn(|c| b[c] - dot(b, x) * x[c]));
    let z = [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]];
    [x, y, z].map(|axis| axis.map(|c| c + 1e-5 * (rng.unit() - 0.5)))
}

#[test]
fn pinhole_rays_on_the_gpu_are_the_hosts_bit_for_bit() {
    let mut rng = Rng::new(97);
    let gpu = gpu();
    for case in 0..12 {
        let (views, width, height) = (rng.range(1, 4), rng.range(1, 90), rng.range(1, 70));
        let cameras: Vec<PinholeRays> = (0..views)
            .map(|v| {
                // Cases alternate the first view's kind; the views after it alternate.
                let kind = if (case + v) % 2 == 0 { RayKind::UnitDirection } else { RayKind::UnitDepthPoint };
                let f = rng.uniform(0.3, 400.0);
                let pinhole = Intrinsics {
                    width,
                    height,
                    fx: f,
                    fy: f * rng.uniform(0.8, 1.25),
                    cx: width as f64 * rng.uniform(0.3, 0.7),
                    cy: height as f64 * rng.uniform(0.3, 0.7),
                };
                let position = [0; 3].map(|_| rng.uniform(-40.0, 40.0));
                PinholeRays::new(kind, &pinhole, rotation(&mut rng), position)
            })
            .collect();
        let terms: Vec<f32> = cameras.iter().flat_map(|c| c.gpu_terms(0..width, 0..height)).flatten().collect();
        let rays = views * height * width;
        let terms = gpu.upload("terms", views * (width + height), TERM_FLOATS, &terms).unwrap();
        let out = sentinel_tensor(rays + 3, 3, SENTINEL);
        let mut b = PlanBuilder::new();
        let (ti, oi) = (b.external("terms", &terms), b.external("out", &out));
        let (terms, out_view) = (b.all(ti), b.rows_of(oi, 0, rays));
        let args = PinholeRaysArgs { terms, views, height, width, out: out_view };
        pinhole_rays(&mut b, "rays", args);
        run(b);
        let got = read_written_rows(&out, 0..rays, SENTINEL);
        let want: Vec<f32> = cameras
            .iter()
            .flat_map(|c| (0..height).flat_map(move |i| (0..width).flat_map(move |j| c.ray(i, j))))
            .collect();
        let differ = got.iter().zip(&want).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        let kinds: Vec<RayKind> = cameras.iter().map(|c| c.kind).collect();
        assert_eq!(
            differ,
            0,
            "{kinds:?}, {views} views of {width}x{height}: {differ} of {} values differ from the host's rays",
            want.len()
        );
    }
}
