//! Timing (warm-up, then repeated runs summarised by median, min and max), errors, and the machine record.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

/// Median, minimum and maximum of repeated runs, in milliseconds.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Stats {
    pub median_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
    pub runs: usize,
}

impl Stats {
    pub fn of(samples: &[Duration]) -> Option<Stats> {
        if samples.is_empty() {
            return None;
        }
        let mut ms: Vec<f64> = samples.iter().map(|d| d.as_secs_f64() * 1e3).collect();
        ms.sort_by(f64::total_cmp);
        let n = ms.len();
        let median = if n % 2 == 1 { ms[n / 2] } else { 0.5 * (ms[n / 2 - 1] + ms[n / 2]) };
        Some(Stats { median_ms: median, min_ms: ms[0], max_ms: ms[n - 1], runs: n })
    }
}

/// How many times to run a measurement.
#[derive(Clone, Copy, Debug)]
pub struct Repeats {
    pub warmup: usize,
    /// Keep warming up, unrecorded, until this long has passed: a GPU idle between short submissions holds its
    /// lowest clocks (an H200's at 345 MHz of 1980 in tools/bench/gpu_bench.sh's clocks.csv) until it has been
    /// busy for a while. Zero on CPU adapters.
    pub warm_for: Duration,
    pub runs: usize,
    /// Stop repeating once the measured runs took this long (at least one run is always made).
    pub budget: Duration,
}

/// How long to warm an adapter up before timing it ([`Repeats::warm_for`]): a quarter second on GPUs (the
/// H200's clocks rose from idle within 0.1 s of steady work), nothing on CPU adapters, which keep their clocks.
pub fn warm_for(adapter: wgpu::DeviceType) -> Duration {
    if adapter == wgpu::DeviceType::Cpu {
        Duration::ZERO
    } else {
        Duration::from_millis(250)
    }
}

/// One run's wall time and, when the GPU timed it, its GPU time.
pub struct Sample {
    pub wall: Duration,
    pub gpu: Option<Duration>,
}

/// Runs `run` `warmup` times unrecorded, and on until `warm_for` has passed, then up to `runs` times (within the
/// budget); returns the wall-time and GPU-time statistics (the latter when every run had a GPU time).
pub fn repeat<E>(repeats: Repeats, mut run: impl FnMut() -> Result<Sample, E>) -> Result<(Stats, Option<Stats>), E> {
    let warming = Instant::now();
    let mut warmed = 0;
    while warmed < repeats.warmup || warming.elapsed() < repeats.warm_for {
        run()?;
        warmed += 1;
    }
    let (mut wall, mut gpu) = (Vec::new(), Vec::new());
    let start = Instant::now();
    while wall.len() < repeats.runs.max(1) && (wall.is_empty() || start.elapsed() < repeats.budget) {
        let sample = run()?;
        wall.push(sample.wall);
        gpu.extend(sample.gpu);
    }
    let gpu = if gpu.len() == wall.len() { Stats::of(&gpu) } else { None };
    Ok((Stats::of(&wall).expect("at least one run"), gpu))
}

/// max |a - b| over two equally long slices; infinite if either holds a NaN or infinity.
pub fn max_abs_error(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "compared outputs differ in length");
    a.iter()
        .zip(b)
        .map(|(&x, &y)| if x.is_finite() && y.is_finite() { (x as f64 - y).abs() } else { f64::INFINITY })
        .fold(0.0, f64::max)
}

/// Root-mean-square difference; infinite if either holds a NaN or infinity.
pub fn rms_error(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "compared outputs differ in length");
    let sum: f64 = a.iter().zip(b).map(|(&x, &y)| (x as f64 - y).powi(2)).sum();
    let rms = (sum / a.len().max(1) as f64).sqrt();
    if rms.is_finite() {
        rms
    } else {
        f64::INFINITY
    }
}

/// PSNR in dB of `views` images in [0, 1] against their ground truth: per image, then the mean over images
/// (the paper's metric, as torchmetrics and `render-frame --metrics` compute it).
pub fn psnr(images: &[f32], truth: &[f32], views: usize) -> f64 {
    let per_view = images.len() / views.max(1);
    let total: f64 = images
        .chunks(per_view)
        .zip(truth.chunks(per_view))
        .map(|(image, truth)| {
            let truth: Vec<f64> = truth.iter().map(|&v| v as f64).collect();
            -10.0 * rms_error(image, &truth).powi(2).log10()
        })
        .sum();
    total / views.max(1) as f64
}

/// The machine, for the record: CPU model and threads, memory, OS.
pub fn machine() -> String {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let cpu = cpuinfo
        .lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split(':').nth(1))
        .map_or_else(|| std::env::consts::ARCH.to_string(), |s| s.trim().to_string());
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let memory = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| m.lines().find(|l| l.starts_with("MemTotal")).map(str::to_string))
        .and_then(|l| l.split_whitespace().nth(1).and_then(|kb| kb.parse::<f64>().ok()))
        .map_or(String::new(), |kb| format!(", {:.0} GiB RAM", kb / 1048576.0));
    format!("{cpu}, {threads} threads{memory}, {} {}", std::env::consts::OS, std::env::consts::ARCH)
}
