// Activations and the functions shaders share (prepended to the sources of matmul, matmul_lanes, conv,
// elementwise and gru by kernels/mod.rs).

// The codes of `Params.act` and `Params.mode`: their values are the wrappers' (kernels::Activation,
// kernels::ConvMode), which tests/uniforms.rs checks against these.
const ACT_NONE: u32 = 0u;
const ACT_RELU: u32 = 1u;
const ACT_LEAKY_RELU: u32 = 2u;
// Exact (erf) GELU.
const ACT_GELU: u32 = 3u;
const MODE_OVERWRITE: u32 = 0u;
const MODE_ACCUMULATE: u32 = 1u;
const MODE_RESIDUAL: u32 = 2u;

// 1 / (1 + exp(-v)) without overflow: exp only ever sees -|v| ≤ 0, and for v < 0 the form e / (1 + e),
// e = exp(v), keeps the relative accuracy of the small results.
fn sigmoid(v: vec4<f32>) -> vec4<f32> {
    let e = exp(-abs(v));
    let q = 1.0 / (1.0 + e);
    return select(e * q, q, v >= vec4<f32>(0.0));
}

// tanh without overflow (a GPU's tanh may be (e^2v - 1) / (e^2v + 1), NaN past |v| ≈ 44): with e = exp(-2|v|)
// ≤ 1, tanh|v| = (1 - e) / (1 + e); for |v| < 0.25 the odd series to v^9 (relative error < 1e-8) keeps the
// relative accuracy that 1 - e loses near 0.
fn tanh_stable(v: vec4<f32>) -> vec4<f32> {
    let a = abs(v);
    let e = exp(-2.0 * a);
    let large = (1.0 - e) / (1.0 + e);
    let z = v * v;
    let series = a * (1.0 + z * (-0.33333333 + z * (0.13333333 + z * (-0.053968254 + z * 0.021869488))));
    return sign(v) * select(large, series, a < vec4<f32>(0.25));
}

// erf in f32, after FreeBSD's s_erff.c (Sun Microsystems 1993, freely redistributable): rational
// approximations on |x| in [0, 0.84375), [0.84375, 1.25), [1.25, 1/0.35) and [1/0.35, 4), and ±1 beyond,
// where 1 - erf(4) = 1.5e-8. s_erff splits x² in exp(-x²) to keep erfc's relative error small, which an
// absolute error target does not need. Branch-free (every piece is evaluated, then selected) since the
// lanes of a SIMD group take different pieces anyway. Max |error| against float64 erf, measured by
// tests/kernels/matmul.rs (gelu_erf_accuracy) over [-10, 10]: 8.3e-8.
fn erf(v: vec4<f32>) -> vec4<f32> {
    let a = abs(v);
    let z = a * a;
    let pp = 1.2837916613e-01 + z * (-3.2504209876e-01 + z * (-2.8481749818e-02
        + z * (-5.7702702470e-03 + z * -2.3763017452e-05)));
    let qq = 1.0 + z * (3.9791721106e-01 + z * (6.5022252500e-02 + z * (5.0813062117e-03
        + z * (1.3249473704e-04 + z * -3.9602282413e-06))));
    let small = a + a * (pp / qq);

    let s = a - 1.0;
    let pa = -2.3621185683e-03 + s * (4.1485610604e-01 + s * (-3.7220788002e-01 + s * (3.1834661961e-01
        + s * (-1.1089469492e-01 + s * (3.5478305072e-02 + s * -2.1663755178e-03)))));
    let qa = 1.0 + s * (1.0642088205e-01 + s * (5.4039794207e-01 + s * (7.1828655899e-02
        + s * (1.2617121637e-01 + s * (1.3637083583e-02 + s * 1.1984500103e-02)))));
    let middle = 8.4506291151e-01 + pa / qa;

    // erfc(a) = exp(-a² - 0.5625 + R(1/a²) / S(1/a²)) / a.
    let t = 1.0 / z;
    let ra = -9.8649440333e-03 + t * (-6.9385856390e-01 + t * (-1.0558626175e+01 + t * (-6.2375331879e+01
        + t * (-1.6239666748e+02 + t * (-1.8460508728e+02 + t * (-8.1287437439e+01 + t * -9.8143291473e+00))))));
    let sa = 1.0 + t * (1.9651271820e+01 + t * (1.3765776062e+02 + t * (4.3456588745e+02 + t * (6.4538726807e+02
        + t * (4.2900814819e+02 + t * (1.0863500214e+02 + t * (6.5702495575e+00 + t * -6.0424413532e-02)))))));
    let rb = -9.8649431020e-03 + t * (-7.9928326607e-01 + t * (-1.7757955551e+01 + t * (-1.6063638306e+02
        + t * (-6.3756646729e+02 + t * (-1.0250950928e+03 + t * -4.8351919556e+02)))));
    let sb = 1.0 + t * (3.0338060379e+01 + t * (3.2579251099e+02 + t * (1.5367296143e+03 + t * (3.1998581543e+03
        + t * (2.5530502930e+03 + t * (4.7452853394e+02 + t * -2.2440952301e+01))))));
    let near = a < vec4<f32>(2.857142857);
    let tail = 1.0 - exp(-z - 0.5625 + select(rb / sb, ra / sa, near)) / a;

    var e = select(vec4<f32>(1.0), tail, a < vec4<f32>(4.0));
    e = select(e, middle, a < vec4<f32>(1.25));
    e = select(e, small, a < vec4<f32>(0.84375));
    return sign(v) * e;
}

fn activate(v: vec4<f32>, act: u32, slope: f32) -> vec4<f32> {
    switch act {
        case ACT_RELU: {
            return max(v, vec4<f32>(0.0));
        }
        case ACT_LEAKY_RELU: {
            return select(slope * v, v, v >= vec4<f32>(0.0));
        }
        case ACT_GELU: {
            return (0.5 * v) * (1.0 + erf(v * 0.70710678));
        }
        default: {
            return v;
        }
    }
}

// What a matmul or convolution writes: its sum `v` (bias added) against what out held (`prior`; read it
// only when mode is not MODE_OVERWRITE): MODE_OVERWRITE act(v), MODE_ACCUMULATE prior + act(v), MODE_RESIDUAL
// act(prior + v) (the residual before the activation). Columns past the output's width (`real` false) become 0 before
// the accumulation, where prior is 0 too: the padding stays zero.
fn epilogue(v: vec4<f32>, prior: vec4<f32>, mode: u32, act: u32, slope: f32, real: vec4<bool>) -> vec4<f32> {
    var r = v;
    if (mode == MODE_RESIDUAL) {
        r += prior;
    }
    r = select(vec4<f32>(0.0), activate(r, act, slope), real);
    if (mode == MODE_ACCUMULATE) {
        r += prior;
    }
    return r;
}
