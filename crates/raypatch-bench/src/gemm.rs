//! `raypatch-bench --gemm`: the linear layers that dominate the official RP-SRT's render and encode, alone,
//! on every matmul kernel the adapter runs, next to PyTorch's `F.linear` on the same shapes and machine
//! (`tools/bench/bench_gemm_pytorch.py`; on the CPU, or cuBLAS on a CUDA GPU): GMAC/s per shape, in gemm.json and
//! gemm.md.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use raypatch_engine::device::KernelChoice;
use raypatch_engine::device::MatmulKernel;
use raypatch_engine::kernels::matmul::{linear, LinearArgs};
use raypatch_engine::kernels::Activation;
use raypatch_engine::plan::PlanBuilder;
use raypatch_engine::Gpu;
use raypatch_reference::Rng;
use serde::{Deserialize, Serialize};

use crate::measure::{repeat, warm_for, Repeats, Sample, Stats};
use crate::pytorch::{source_file, Torch};
use crate::report::write_file;

/// (M, K, N, where): x `[M, K]`, weight `[N, K]`; the official srt_MDBN_32 / rpsrt_MDBN_8_32 at 120x160.
pub(crate) const SHAPES: [(usize, usize, usize, &str); 6] = [
    (300, 180, 1536, "RP-SRT k=8 render: out_mlp.0 (300 patch queries)"),
    (300, 1536, 1536, "RP-SRT k=8 render: out_mlp.2, out_mlp.4"),
    (4800, 768, 2304, "encode: transformer to_qkv (4800 tokens)"),
    (4800, 768, 768, "encode: transformer to_out"),
    (4800, 768, 1536, "encode: transformer MLP up"),
    (4800, 1536, 768, "encode: transformer MLP down"),
];

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GemmRecord {
    pub m: usize,
    pub k: usize,
    pub n: usize,
    pub place: String,
    /// (kernel, times) for every kernel the adapter runs.
    pub engine: Vec<(String, Stats)>,
    pub pytorch: Option<Stats>,
}

impl GemmRecord {
    fn gmacs(&self, stats: &Stats) -> f64 {
        (self.m * self.k * self.n) as f64 / (stats.median_ms * 1e-3) / 1e9
    }
}

/// Times one linear layer (bias, no activation) on `kernel`: `runs` executions after a warm-up, each waited
/// for. `Lanes` includes packing x (the weight is packed once, in the warm-up).
fn time_linear(gpu: &Gpu, kernel: MatmulKernel, (m, k, n): (usize, usize, usize), runs: usize) -> Result<Stats> {
    let mut rng = Rng::new(7);
    let x = gpu.upload("x", m, k, &rng.vec_f32(m * k, -1.0, 1.0))?;
    let w = gpu.upload("w", n, k, &rng.vec_f32(n * k, -1.0, 1.0))?;
    let b = gpu.upload("b", 1, n, &rng.vec_f32(n, -1.0, 1.0))?;
    let mut plan = PlanBuilder::new();
    plan.kernels = KernelChoice { matmul: kernel, pinned: true, ..gpu.kernels };
    let (x, weight, bias) = (plan.external("x", &x), plan.constant("w", &w), plan.constant("b", &b));
    let out = plan.output("out", m, n);
    let (x, out) = (plan.all(x), plan.all(out));
    let act = Activation::None;
    linear(&mut plan, "linear", LinearArgs { x, weight, bias: Some(bias), out, act, accumulate: false, norm: None });
    let plan = plan.build(gpu)?;
    let repeats = Repeats { warmup: 1, warm_for: warm_for(gpu.info.device_type), runs, budget: Duration::MAX };
    let (wall, _) = repeat(repeats, || -> Result<Sample> {
        let start = Instant::now();
        plan.execute(gpu);
        gpu.wait()?;
        Ok(Sample { wall: start.elapsed(), gpu: None })
    })?;
    Ok(wall)
}

#[derive(Deserialize)]
struct TorchGemm {
    shapes: Vec<Stats>,
}

fn pytorch(torch: &Torch, runs: usize) -> Result<Vec<Stats>> {
    let mut command = Command::new("python3");
    command.arg(source_file("tools/bench/bench_gemm_pytorch.py"));
    command.args(["--repeats", &runs.to_string(), "--device", torch.device.name()]);
    for (m, k, n, _) in SHAPES {
        command.args(["--shape", &format!("{m}x{k}x{n}")]);
    }
    let out = command.output().context("running python3 tools/bench/bench_gemm_pytorch.py")?;
    if !out.status.success() {
        bail!("tools/bench/bench_gemm_pytorch.py failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let json: TorchGemm =
        serde_json::from_slice(&out.stdout).context("tools/bench/bench_gemm_pytorch.py printed no result")?;
    Ok(json.shapes)
}

/// Measures every shape on every kernel `gpu` runs, or on `only` (and PyTorch when `torch`), writes gemm.json
/// and gemm.md into `out`, and returns the Markdown table.
pub fn run(gpu: &Gpu, only: Option<MatmulKernel>, torch: Option<&Torch>, runs: usize, out: &Path) -> Result<String> {
    let kernels: Vec<MatmulKernel> = MatmulKernel::ALL
        .into_iter()
        .filter(|&k| only.is_none_or(|o| o == k) && k.supported(&gpu.info, gpu.features).is_ok())
        .collect();
    let torch_times = torch.map(|t| pytorch(t, runs)).transpose()?;
    let mut records = Vec::new();
    for (i, (m, k, n, place)) in SHAPES.into_iter().enumerate() {
        let mut engine = Vec::new();
        for &kernel in &kernels {
            let stats = time_linear(gpu, kernel, (m, k, n), runs)?;
            println!("{m}x{k}x{n} {kernel:?}: {:.2} ms", stats.median_ms);
            engine.push((format!("{kernel:?}"), stats));
        }
        let pytorch = torch_times.as_ref().map(|t| t[i]);
        records.push(GemmRecord { m, k, n, place: place.to_string(), engine, pytorch });
    }
    let mut table = format!(
        "Adapter: {}. PyTorch: {}.\n\n| M x K x N | where |",
        gpu.describe(),
        torch.map_or("not timed".to_string(), Torch::describe)
    );
    for kernel in &kernels {
        table += &format!(" {kernel:?} GMAC/s |");
    }
    table += " PyTorch GMAC/s | PyTorch / fastest |\n|---|---|";
    table += &"---|".repeat(kernels.len() + 2);
    table += "\n";
    for r in &records {
        table += &format!("| {}x{}x{} | {} |", r.m, r.k, r.n, r.place);
        for (_, stats) in &r.engine {
            table += &format!(" {:.1} |", r.gmacs(stats));
        }
        let fastest = r.engine.iter().map(|(_, s)| r.gmacs(s)).fold(0.0, f64::max);
        match &r.pytorch {
            Some(t) => table += &format!(" {:.1} | {:.2} |\n", r.gmacs(t), r.gmacs(t) / fastest),
            None => table += " - | - |\n",
        }
    }
    write_file(&out.join("gemm.json"), serde_json::to_string_pretty(&records)?.as_bytes())?;
    write_file(&out.join("gemm.md"), table.as_bytes())?;
    Ok(table)
}
