//! `raypatch-bench --coop-tune --out DIR`: the tensor kernels' GEMM tuner. Times the engine's `linear_coop`
//! (`MatmulKernel::Coop`, f16 weights as `--precision f16-act` stores them) under every workgroup tiling that fits
//! the adapter (`CoopShape::fits`: sg_m, sg_n in {1, 2, 4}, bk in {tile, 2·tile, 4·tile}; a tiling is a set of
//! override constants, `CoopShape::constants`) on the official models' GEMM shapes of each shape class
//! ([`GemmClass`]: small, at most 2048 rows of out, large, more), checks each tiling's output against float64,
//! keeps the fastest per class (least total time over the class's shapes) and writes it into the engine's
//! tuning file (`device::COOP_TUNING_FILE` in raypatch's cache folder, or `--tuning-file`), replacing only this
//! adapter's lines. Then times the tensor GEMM at 4096³ (`--quick`: 512³) on the large class's tiling. Writes
//! coop-tune.md and coop-tune.json into DIR. `--quick`: small stand-in shapes, to try it on a CPU adapter
//! (Mesa 26 lavapipe in `.ci/coop-chroot.sh`'s chroot). `tools/bench/gpu_bench.sh OUT tensor` runs it.

use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use raypatch_engine::device::{CoopShape, CoopTiling, GemmClass, KernelChoice, MatmulKernel};
use raypatch_engine::kernels::matmul::{linear, LinearArgs};
use raypatch_engine::kernels::Activation;
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::Gpu;
use raypatch_reference::Rng;
use serde::{Deserialize, Serialize};

use crate::gemm::SHAPES;
use crate::measure::warm_for;
use crate::report::write_file;

/// (M, K, N, where) of the renders with many query rows, beside the GEMM benchmark's official shapes
/// (`gemm::SHAPES`: srt_MDBN_32 and rpsrt_MDBN_8_32 at 120x160); x `[M, K]`, weight `[N, K]`.
const MANY_QUERY_SHAPES: [(usize, usize, usize, &str); 3] = [
    (9600, 1536, 1536, "RP-SRT k=8, 32 views: out_mlp hidden layers (9600 patch queries)"),
    (19200, 180, 1536, "SRT 120x160 render: out_mlp.0 (19200 queries)"),
    (19200, 1536, 1536, "SRT 120x160 render: out_mlp hidden layers"),
];
/// `--quick`'s stand-ins: one shape a class, small enough for lavapipe.
pub const QUICK_SHAPES: [(usize, usize, usize, &str); 2] = [
    (300, 180, 384, "stand-in for the small class (RP-SRT k=8 render, narrower)"),
    (2112, 128, 192, "stand-in for the large class (just over 2048 rows)"),
];

/// The side of the square GEMM whose TFLOP/s the tuner reports (the 4096³), and `--quick`'s.
pub const SQUARE: usize = 4096;
pub const QUICK_SQUARE: usize = 512;

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
pub struct Tiling {
    pub sg_m: u32,
    pub sg_n: u32,
    pub bk: u32,
}

impl From<CoopTiling> for Tiling {
    fn from(t: CoopTiling) -> Tiling {
        Tiling { sg_m: t.sg_m, sg_n: t.sg_n, bk: t.bk }
    }
}

impl From<Tiling> for CoopTiling {
    fn from(t: Tiling) -> CoopTiling {
        CoopTiling { sg_m: t.sg_m, sg_n: t.sg_n, bk: t.bk }
    }
}

impl std::fmt::Display for Tiling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "sg {}x{}, bk {}", self.sg_m, self.sg_n, self.bk)
    }
}

/// One tiling's times on a class's shapes (ms per GEMM, the fastest run), or why it was left out.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Candidate {
    pub tiling: Tiling,
    pub ms: Vec<f64>,
    pub total_ms: Option<f64>,
    pub error: Option<String>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClassResult {
    pub class: String,
    /// (M, K, N, where) of the class's shapes.
    pub shapes: Vec<(usize, usize, usize, String)>,
    pub candidates: Vec<Candidate>,
    pub best: Option<Tiling>,
    /// The engine's default tiling's total, for the speed-up.
    pub default_total_ms: Option<f64>,
}

/// The square GEMM's figure.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Square {
    pub size: usize,
    pub tiling: Tiling,
    pub ms: f64,
    pub tflops: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TuneReport {
    pub adapter: String,
    pub device_type: String,
    pub tile: u32,
    pub lanes: u32,
    pub quick: bool,
    pub classes: Vec<ClassResult>,
    pub square: Option<Square>,
    pub square_error: Option<String>,
    /// The tuning file written, and the lines it holds for this adapter.
    pub tuning_file: String,
    pub tuning_lines: Vec<String>,
    /// Candidates left untried when the time budget ran out.
    pub untried: usize,
}

/// What to tune and where to write it.
pub struct TuneOptions<'a> {
    pub quick: bool,
    /// Stop trying new tilings once this long has passed (the tilings tried so far decide).
    pub budget: Option<Duration>,
    pub tuning_file: &'a Path,
    pub out: &'a Path,
}

/// The tilings to try on `shape`'s adapter: the engine's default first, then every sg_m, sg_n in {1, 2, 4} and
/// bk in {tile, 2·tile, 4·tile} that fits the adapter's limits.
pub fn candidates(shape: &CoopShape, limits: &wgpu::Limits) -> Vec<CoopTiling> {
    let mut all: Vec<CoopTiling> = shape.default_tiling(limits).into_iter().collect();
    for sg_m in [1, 2, 4] {
        for sg_n in [1, 2, 4] {
            for bk in [shape.tile, 2 * shape.tile, 4 * shape.tile] {
                let t = CoopTiling { sg_m, sg_n, bk };
                if !all.contains(&t) {
                    all.push(t);
                }
            }
        }
    }
    all.retain(|&t| shape.fits(t, limits).is_ok());
    all
}

/// The tuning file's lines for `adapter`: `adapter<TAB>class<TAB>sg_m<TAB>sg_n<TAB>bk`.
pub fn tuning_lines(adapter: &str, best: &[(GemmClass, CoopTiling)]) -> Vec<String> {
    best.iter().map(|(class, t)| format!("{adapter}\t{}\t{}\t{}\t{}", class.name(), t.sg_m, t.sg_n, t.bk)).collect()
}

/// `existing` (the tuning file's text, empty if none) with `adapter`'s lines of the classes in `best` replaced by
/// `best`'s; every other line (other adapters, this adapter's other classes, comments) kept in its place, the new
/// lines at the end. An adapter name with a tab or a line break cannot be written (the engine would not read it).
pub fn merge_tuning(existing: &str, adapter: &str, best: &[(GemmClass, CoopTiling)]) -> Result<String> {
    if adapter.is_empty() || adapter.contains(['\t', '\n', '\r']) {
        bail!("adapter name {adapter:?}: empty, or holds a tab or a line break; the tuning file cannot name it");
    }
    let replaced = |line: &str| {
        let mut fields = line.split('\t');
        fields.next() == Some(adapter) && fields.next().is_some_and(|c| best.iter().any(|(b, _)| b.name() == c))
    };
    let mut text = String::new();
    for line in existing.lines().filter(|l| !l.trim().is_empty() && !replaced(l)) {
        text += line;
        text += "\n";
    }
    for line in tuning_lines(adapter, best) {
        text += &line;
        text += "\n";
    }
    Ok(text)
}

/// Writes `best` into the tuning file at `path` (created with its folder; merged with what it holds), through a
/// temporary name so that the engine never reads half a file.
pub fn write_tuning(path: &Path, adapter: &str, best: &[(GemmClass, CoopTiling)]) -> Result<()> {
    let existing = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
    };
    let text = merge_tuning(&existing, adapter, best)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    }
    let partial = path.with_extension("tsv.partial");
    std::fs::write(&partial, text).with_context(|| format!("{}: cannot write", partial.display()))?;
    std::fs::rename(&partial, path).with_context(|| format!("{}: cannot write", path.display()))?;
    Ok(())
}

/// A value rounded to f16 and back (f16-representable data: the kernel's rounding as it stages is then exact).
fn f16_exact(rng: &mut Rng, n: usize) -> Vec<f32> {
    rng.vec_f32(n, -1.0, 1.0).into_iter().map(|v| half::f16::from_f32(v).to_f32()).collect()
}

/// The kernel profile that runs every linear layer on `linear_coop` with `tiling` in both classes.
fn choice_with(gpu: &Gpu, shape: CoopShape, tiling: CoopTiling) -> KernelChoice {
    let mut choice = gpu.kernels.at_precision(true);
    choice.matmul = MatmulKernel::Coop;
    choice.coop = Some(CoopShape { tilings: [tiling; 2], ..shape });
    // Never moved to `Rows` for narrow outputs: the tensor kernel is what is timed.
    choice.pinned = true;
    choice
}

/// Milliseconds per GEMM (bias, no activation) of `linear_coop` with `tiling` on (m, k, n): a plan of `reps`
/// copies of it (one submit: a GPU's submission overhead shared), run once to warm, then `runs` times; the
/// fastest run. With `check`, the output is compared with float64 first (an error names the worst output).
fn time_tiling(
    gpu: &Gpu,
    shape: CoopShape,
    tiling: CoopTiling,
    (m, k, n): (usize, usize, usize),
    (reps, runs): (usize, usize),
    warm: Duration,
    check: bool,
) -> Result<f64> {
    let mut rng = Rng::new((m * 131 + k * 17 + n) as u64);
    let (xs, ws, bs) = (f16_exact(&mut rng, m * k), f16_exact(&mut rng, n * k), f16_exact(&mut rng, n));
    let x = gpu.upload("x", m, k, &xs)?;
    let w = gpu.upload_f16("w", n, k, &ws)?;
    let b = gpu.upload("b", 1, n, &bs)?;
    let mut plan = PlanBuilder::new();
    plan.kernels = choice_with(gpu, shape, tiling);
    let (x, weight, bias) = (plan.external("x", &x), plan.constant("w", &w), plan.constant("b", &b));
    let out_id = plan.output("out", m, n);
    let (x, out) = (plan.all(x), plan.all(out_id));
    for i in 0..reps.max(1) {
        let args =
            LinearArgs { x, weight, bias: Some(bias), out, act: Activation::None, accumulate: false, norm: None };
        linear(&mut plan, &format!("linear{i}"), args);
    }
    let plan = plan.build(gpu)?;
    if check {
        let got = plan.execute_and_read(gpu, &[], &[out_id])?.remove(0);
        let mut samples: Vec<(usize, usize)> = vec![(0, 0), (m - 1, n - 1), (0, n - 1), (m - 1, 0)];
        samples.extend((0..252).map(|_| (rng.range(0, m - 1), rng.range(0, n - 1))));
        // f32 sums of exact f16 products: K-dependent rounding only.
        let bound = 1e-6 * k as f64 + 1e-5;
        for (i, j) in samples {
            let expected =
                f64::from(bs[j]) + (0..k).map(|c| f64::from(xs[i * k + c]) * f64::from(ws[j * k + c])).sum::<f64>();
            let e = (f64::from(got[i * n + j]) - expected).abs();
            if !(e <= bound) {
                bail!(
                    "{m}x{k}x{n}: out[{i}, {j}] = {} where float64 gives {expected:.6} (error {e:.2e})",
                    got[i * n + j]
                );
            }
        }
    }
    let run = || -> Result<Duration> {
        let start = Instant::now();
        plan.execute(gpu);
        gpu.wait()?;
        Ok(start.elapsed())
    };
    let warming = Instant::now();
    run()?;
    while warming.elapsed() < warm {
        run()?;
    }
    let mut best = Duration::MAX;
    for _ in 0..runs.max(1) {
        best = best.min(run()?);
    }
    Ok(best.as_secs_f64() * 1e3 / reps.max(1) as f64)
}

/// Copies of a GEMM of `macs` multiply-adds one timed plan holds: about 2 G multiply-adds (tens of microseconds
/// of a GPU's submission overhead shared among them), up to 64; one on CPU adapters.
fn reps_for(on_cpu: bool, macs: usize) -> usize {
    if on_cpu {
        1
    } else {
        (2_000_000_000 / macs.max(1)).clamp(1, 64)
    }
}

/// The shapes of each class tuned.
pub fn class_shapes(quick: bool) -> Vec<(GemmClass, Vec<(usize, usize, usize, &'static str)>)> {
    if quick {
        vec![(GemmClass::Small, vec![QUICK_SHAPES[0]]), (GemmClass::Large, vec![QUICK_SHAPES[1]])]
    } else {
        let all = SHAPES.iter().chain(&MANY_QUERY_SHAPES);
        let of = |class| all.clone().filter(|&&(m, ..)| GemmClass::of_rows(m) == class).copied().collect();
        vec![(GemmClass::Small, of(GemmClass::Small)), (GemmClass::Large, of(GemmClass::Large))]
    }
}

/// Tunes `gpu`'s tensor GEMM (the module's header), writes the tuning file and the reports; returns the report.
pub fn run(gpu: &Gpu, options: &TuneOptions) -> Result<TuneReport> {
    let Some(shape) = gpu.kernels.coop else {
        bail!("{}: no tensor kernels here (the device has no cooperative matrices the engine can use)", gpu.describe());
    };
    let on_cpu = gpu.info.device_type == wgpu::DeviceType::Cpu;
    let runs = if on_cpu { 2 } else { 10 };
    let tilings = candidates(&shape, &gpu.limits);
    let started = Instant::now();
    let over_budget = || options.budget.is_some_and(|b| started.elapsed() > b);
    println!(
        "coop-tune on {}: {}x{}x{} f16 tiles, {}-lane subgroups; {} tilings fit: {}",
        gpu.describe(),
        shape.tile,
        shape.tile,
        shape.tile,
        shape.lanes,
        tilings.len(),
        tilings.iter().map(|&t| Tiling::from(t).to_string()).collect::<Vec<_>>().join("; ")
    );
    let classes = class_shapes(options.quick);
    let mut results: Vec<ClassResult> = classes
        .iter()
        .map(|(class, shapes)| ClassResult {
            class: class.name().into(),
            shapes: shapes.iter().map(|&(m, k, n, w)| (m, k, n, w.to_string())).collect(),
            candidates: Vec::new(),
            best: None,
            default_total_ms: None,
        })
        .collect();
    let mut untried = 0;
    let mut warm = warm_for(gpu.info.device_type);
    for (i, &tiling) in tilings.iter().enumerate() {
        if i > 0 && over_budget() {
            untried = tilings.len() - i;
            println!("coop-tune: the time budget has passed: {untried} tilings left untried");
            break;
        }
        // Checked once a tiling, on edges of its tiles and K steps, then on a deep K that splits.
        let checked = [(257, 200, 190), (40, 1500, 72)]
            .into_iter()
            .try_for_each(|s| time_tiling(gpu, shape, tiling, s, (1, 1), Duration::ZERO, true).map(|_| ()));
        for ((_, shapes), result) in classes.iter().zip(&mut results) {
            let mut candidate = Candidate { tiling: tiling.into(), ms: Vec::new(), total_ms: None, error: None };
            let timed = checked.as_ref().map_err(|e| anyhow::anyhow!("{e:#}")).and_then(|()| {
                shapes
                    .iter()
                    .map(|&(m, k, n, _)| {
                        let reps = reps_for(on_cpu, m * k * n);
                        let ms = time_tiling(gpu, shape, tiling, (m, k, n), (reps, runs), warm, false);
                        // The GPU's clocks rise once: the first timing warms them.
                        warm = Duration::ZERO;
                        ms
                    })
                    .collect::<Result<Vec<f64>>>()
            });
            match timed {
                Ok(ms) => {
                    candidate.total_ms = Some(ms.iter().sum());
                    candidate.ms = ms;
                }
                Err(e) => candidate.error = Some(format!("{e:#}").lines().next().unwrap_or("").to_string()),
            }
            println!(
                "  {} {}: {}",
                result.class,
                candidate.tiling,
                match (&candidate.total_ms, &candidate.error) {
                    (Some(total), _) => format!("{total:.3} ms ({} shapes)", candidate.ms.len()),
                    (None, Some(e)) => format!("left out: {e}"),
                    (None, None) => "left out".into(),
                }
            );
            if i == 0 {
                result.default_total_ms = candidate.total_ms;
            }
            result.candidates.push(candidate);
        }
    }
    let mut best = Vec::new();
    for ((class, _), result) in classes.iter().zip(&mut results) {
        let fastest =
            result.candidates.iter().filter_map(|c| Some((c.tiling, c.total_ms?))).min_by(|a, b| a.1.total_cmp(&b.1));
        result.best = fastest.map(|(t, _)| t);
        if let Some(t) = result.best {
            best.push((*class, CoopTiling::from(t)));
        }
    }
    if !best.is_empty() {
        write_tuning(options.tuning_file, &gpu.info.name, &best)?;
        println!("coop-tune: wrote {} ({} lines for this adapter)", options.tuning_file.display(), best.len());
    }
    // The square GEMM on the large class's tiling (the engine's where none was timed).
    let side = if options.quick { QUICK_SQUARE } else { SQUARE };
    let large =
        best.iter().find(|(c, _)| *c == GemmClass::Large).map_or(shape.tiling(GemmClass::LARGE_ROWS + 1), |b| b.1);
    let reps = reps_for(on_cpu, side * side * side);
    let square =
        time_tiling(gpu, shape, large, (side, side, side), (reps, runs), warm_for(gpu.info.device_type), false);
    let (square, square_error) = match square {
        Ok(ms) => {
            let tflops = 2.0 * (side as f64).powi(3) / (ms * 1e-3) / 1e12;
            println!("coop-tune: {side}^3 on {}: {ms:.3} ms, {tflops:.3} TFLOP/s", Tiling::from(large));
            (Some(Square { size: side, tiling: large.into(), ms, tflops }), None)
        }
        Err(e) => (None, Some(format!("{e:#}"))),
    };
    let report = TuneReport {
        adapter: gpu.info.name.clone(),
        device_type: format!("{:?}", gpu.info.device_type),
        tile: shape.tile,
        lanes: shape.lanes,
        quick: options.quick,
        classes: results,
        square,
        square_error,
        tuning_file: options.tuning_file.display().to_string(),
        tuning_lines: tuning_lines(&gpu.info.name, &best),
        untried,
    };
    write_file(&options.out.join("coop-tune.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;
    write_file(&options.out.join("coop-tune.md"), markdown(&report).as_bytes())?;
    Ok(report)
}

/// The report as Markdown: per class, each tiling's times on each shape, the fastest marked; the square GEMM.
pub fn markdown(r: &TuneReport) -> String {
    let mut text = format!(
        "# The tensor GEMM's tilings (raypatch-bench --coop-tune{})\n\nAdapter: {} ({}); {t}x{t}x{t} f16 \
         cooperative matrices, {} lanes. Tuning file: {}.\n",
        if r.quick { " --quick" } else { "" },
        r.adapter,
        r.device_type,
        r.lanes,
        r.tuning_file,
        t = r.tile
    );
    if r.untried > 0 {
        let _ = writeln!(text, "\n{} tilings were left untried: the time budget had passed.", r.untried);
    }
    for c in &r.classes {
        let _ = write!(text, "\n## Class {}\n\nms per GEMM (the fastest run):\n\n| tiling |", c.class);
        for (m, k, n, _) in &c.shapes {
            let _ = write!(text, " {m}x{k}x{n} |");
        }
        text += " total ms | GFLOP/s |\n|---|";
        text += &"---|".repeat(c.shapes.len() + 2);
        text += "\n";
        let flop: f64 = c.shapes.iter().map(|(m, k, n, _)| 2.0 * (m * k * n) as f64).sum();
        for cand in &c.candidates {
            let mark = if Some(cand.tiling) == c.best { " **fastest**" } else { "" };
            let _ = write!(text, "| {}{mark} |", cand.tiling);
            match (cand.total_ms, &cand.error) {
                (Some(total), _) => {
                    for ms in &cand.ms {
                        let _ = write!(text, " {ms:.4} |");
                    }
                    let _ = writeln!(text, " {total:.4} | {:.1} |", flop / (total * 1e-3) / 1e9);
                }
                (None, e) => {
                    let why = e.as_deref().unwrap_or("not timed").replace('|', "/");
                    let _ = writeln!(text, " {why} |{}", " - |".repeat(c.shapes.len() + 1));
                }
            }
        }
        let best = c.best.and_then(|b| c.candidates.iter().find(|x| x.tiling == b)).and_then(|b| b.total_ms);
        if let (Some(best), Some(default)) = (best, c.default_total_ms) {
            let _ = writeln!(text, "\nFastest: {} ({:.2}x the default's speed).", c.best.expect("set"), default / best);
        }
        text += "\nShapes: ";
        text += &c.shapes.iter().map(|(m, k, n, w)| format!("{m}x{k}x{n} ({w})")).collect::<Vec<_>>().join("; ");
        text += ".\n";
    }
    match (&r.square, &r.square_error) {
        (Some(s), _) => {
            let _ = writeln!(
                text,
                "\n## {n}x{n}x{n}\n\n{:.3} ms, **{:.3} TFLOP/s** on {} (the large class's tiling).",
                s.ms,
                s.tflops,
                s.tiling,
                n = s.size
            );
        }
        (None, Some(e)) => {
            let _ = writeln!(text, "\n## The square GEMM\n\nNot measured: {e}");
        }
        (None, None) => {}
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(tile: u32, lanes: u32) -> CoopShape {
        let t = CoopTiling::preferred(tile)[0];
        CoopShape { tile, lanes, tilings: [t; 2], workgroup_bytes: 32768 }
    }

    #[test]
    fn candidates_start_with_the_default_and_fit_the_limits() {
        let limits = wgpu::Limits { max_compute_workgroup_storage_size: 49152, ..wgpu::Limits::default() };
        let c = candidates(&shape(16, 32), &limits);
        assert_eq!(c[0], CoopTiling::preferred(16)[0]);
        assert!(c.len() > 1 && c.len() <= 27);
        let s = shape(16, 32);
        assert!(c.iter().all(|&t| s.fits(t, &limits).is_ok()));
        assert!(c.iter().all(|t| [16, 32, 64].contains(&t.bk) && [1, 2, 4].contains(&t.sg_m)));
        // 4x4 subgroups of 32 lanes are 512 invocations: over the default limit of 256.
        assert!(!c.iter().any(|t| t.sg_m == 4 && t.sg_n == 4));
        let tight = wgpu::Limits { max_compute_workgroup_storage_size: 16384, ..limits };
        assert!(candidates(&shape(16, 32), &tight).len() < c.len());
    }

    #[test]
    fn the_merge_replaces_only_this_adapters_lines_of_the_classes_written() {
        let small = CoopTiling { sg_m: 1, sg_n: 4, bk: 32 };
        let large = CoopTiling { sg_m: 4, sg_n: 2, bk: 64 };
        let existing =
            "GPU A\tsmall\t2\t2\t32\nGPU B\tsmall\t1\t1\t16\nGPU A\tlarge\t2\t2\t32\n\nGPU B\tlarge\t4\t4\t64\n";
        let merged = merge_tuning(existing, "GPU A", &[(GemmClass::Small, small), (GemmClass::Large, large)]).unwrap();
        assert_eq!(
            merged,
            "GPU B\tsmall\t1\t1\t16\nGPU B\tlarge\t4\t4\t64\nGPU A\tsmall\t1\t4\t32\nGPU A\tlarge\t4\t2\t64\n"
        );
        // One class written: this adapter's other class is kept.
        let merged = merge_tuning(existing, "GPU A", &[(GemmClass::Large, large)]).unwrap();
        assert!(merged.contains("GPU A\tsmall\t2\t2\t32\n") && merged.ends_with("GPU A\tlarge\t4\t2\t64\n"));
        assert_eq!(merged.matches("GPU A\tlarge").count(), 1);
        // A name that only starts like this adapter's is another adapter.
        let merged = merge_tuning("GPU A2\tsmall\t1\t1\t16\n", "GPU A", &[(GemmClass::Small, small)]).unwrap();
        assert_eq!(merged, "GPU A2\tsmall\t1\t1\t16\nGPU A\tsmall\t1\t4\t32\n");
        assert_eq!(merge_tuning("", "GPU A", &[]).unwrap(), "");
        assert!(merge_tuning("", "bad\tname", &[(GemmClass::Small, small)]).is_err());
        assert!(merge_tuning("", "", &[(GemmClass::Small, small)]).is_err());
    }

    #[test]
    fn the_engine_reads_what_the_tuner_writes() {
        let limits = wgpu::Limits { max_compute_workgroup_storage_size: 49152, ..wgpu::Limits::default() };
        let small = CoopTiling { sg_m: 1, sg_n: 2, bk: 16 };
        let large = CoopTiling { sg_m: 2, sg_n: 1, bk: 64 };
        let text = merge_tuning(
            "other\tsmall\t1\t1\t16\n",
            "lavapipe",
            &[(GemmClass::Small, small), (GemmClass::Large, large)],
        )
        .unwrap();
        let tuned = shape(16, 32).tuned(&text, "lavapipe", &limits);
        assert_eq!(tuned.tilings, [small, large]);
        assert_eq!(shape(16, 32).tuned(&text, "other", &limits).tilings[1], CoopTiling::preferred(16)[0]);
    }

    #[test]
    fn the_tuning_file_is_written_and_merged_on_disk() {
        let dir = std::env::temp_dir().join(format!("raypatch-coop-tune-{}", std::process::id()));
        let path = dir.join("sub").join("coop-tuning.tsv");
        let t = CoopTiling { sg_m: 2, sg_n: 4, bk: 32 };
        write_tuning(&path, "A", &[(GemmClass::Small, t)]).unwrap();
        write_tuning(&path, "B", &[(GemmClass::Large, t)]).unwrap();
        write_tuning(&path, "A", &[(GemmClass::Small, CoopTiling::preferred(16)[0])]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text, "B\tlarge\t2\t4\t32\nA\tsmall\t2\t2\t32\n");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_shape_classes_hold_their_shapes() {
        for (class, shapes) in class_shapes(false).into_iter().chain(class_shapes(true)) {
            assert!(shapes.iter().all(|&(m, ..)| GemmClass::of_rows(m) == class), "{class:?}");
        }
    }
}
