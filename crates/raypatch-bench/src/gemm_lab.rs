//! `raypatch-bench --gemm-lab DIR`: times WGSL linear-layer kernels that are not (yet) the engine's, beside the
//! engine's own, on the shapes of `--gemm` and 2048³, with a sampled float64 check of each output: how a new tiling
//! is tried on a lent GPU before it goes into `shaders/` (docs/PERFORMANCE.md, "The GEMM lab").
//!
//! DIR holds the kernels and `manifest.txt` (written by `tools/bench/gemm_lab.py`), a line per variant:
//! `name file entry tile_m tile_n bindings splits [shaped] [norm]`; `shaped`: compiled for each shape with the
//! override constants the engine gives its shaped pipelines (`kernels::matmul::fixed_shape`), as it runs them on
//! GPUs; `norm` (8 bindings): x's rows layer-normalised in the prologue (`MatmulParams::norm`, a transformer's
//! pre-norm), with random gamma and beta at bindings 5 and 6 and the rows' statistics at 7 (as layernorm.wgsl's
//! `row_stats` writes them; taken here on the CPU, the kernel alone is timed).
//! Every kernel takes `shaders/matmul.wgsl`'s uniform and its bindings 0-4 (and 5-7 when `bindings` is 8), numbers its workgroups `wid.x + wid.y * nwg.x` over ceil(m / tile_m) x
//! ceil(n / tile_n) tiles times `splits` K ranges (`auto`: as the engine splits them, `kernels::matmul::split_k`),
//! and writes split s's sums to rows s·m.. of out (the engine's `linear_tiled` adds the bias in `linear_reduce`,
//! so for it, named `engine*`, the check adds it).

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use raypatch_engine::kernels::matmul::{fixed_shape, split_k, MatmulParams};
use raypatch_engine::Gpu;
use raypatch_reference::Rng;
use wgpu::util::DeviceExt;

use crate::gemm::SHAPES;

#[derive(Debug)]
struct Variant {
    name: String,
    file: String,
    entry: String,
    tile: (usize, usize),
    bindings: u32,
    auto_split: bool,
    shaped: bool,
    norm: bool,
}

fn parse_manifest(path: &Path) -> Result<Vec<Variant>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let mut variants = Vec::new();
    for (number, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#')) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let parsed = (|| -> Option<Variant> {
            let flags = f.iter().rev().take_while(|w| ["shaped", "norm"].contains(w)).count();
            let (fields, flags) = f.split_at(f.len() - flags);
            let [name, file, entry, tile_m, tile_n, bindings, splits] = fields[..] else { return None };
            let norm = flags.contains(&"norm");
            let bindings = bindings.parse().ok().filter(|&b| b == 8 || b == 5 && !norm)?;
            Some(Variant {
                name: name.into(),
                file: file.into(),
                entry: entry.into(),
                tile: (tile_m.parse().ok().filter(|&t| t > 0)?, tile_n.parse().ok().filter(|&t| t > 0)?),
                bindings,
                auto_split: match splits {
                    "1" => false,
                    "auto" => true,
                    _ => return None,
                },
                shaped: flags.contains(&"shaped"),
                norm,
            })
        })();
        match parsed {
            Some(v) => variants.push(v),
            None => bail!(
                "{}:{}: expected `name file entry tile_m tile_n bindings(5|8) splits(1|auto) [shaped] [norm]` (norm: 8 \
                 bindings)",
                path.display(),
                number + 1
            ),
        }
    }
    Ok(variants)
}

/// Times every variant of `dir` whose name contains one of `only` (all when empty) and returns the table.
pub fn run(gpu: &Gpu, dir: &Path, only: &[String]) -> Result<String> {
    let variants = parse_manifest(&dir.join("manifest.txt"))?;
    let on_cpu = gpu.info.device_type == wgpu::DeviceType::Cpu;
    let mut shapes: Vec<(usize, usize, usize)> = SHAPES.iter().map(|&(m, k, n, _)| (m, k, n)).collect();
    shapes.push((2048, 2048, 2048));
    if on_cpu {
        // A smoke run: the small render shapes only.
        shapes.truncate(2);
    }
    let runs = if on_cpu { 1 } else { 20 };
    let mut table =
        String::from("| kernel | M x K x N | K ranges | ms | GMAC/s | max error |\n|---|---|---|---|---|---|\n");
    for v in variants.iter().filter(|v| only.is_empty() || only.iter().any(|o| v.name.contains(o.as_str()))) {
        let path = dir.join(&v.file);
        let source = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
        let unshaped = if v.shaped { None } else { Some(compile(gpu, v, &path, &source, &[])?) };
        for &shape in &shapes {
            let (ms, splits, error) = time_variant(gpu, v, shape, runs, |params| match &unshaped {
                Some(pipeline) => Ok(pipeline.clone()),
                None => compile(gpu, v, &path, &source, &fixed_shape(params)),
            })?;
            let (m, k, n) = shape;
            let gmacs = (m * k * n) as f64 / (ms * 1e-3) / 1e9;
            writeln!(table, "| {} | {m}x{k}x{n} | {splits} | {ms:.3} | {gmacs:.0} | {error:.1e} |", v.name)?;
        }
    }
    Ok(table)
}

/// The pipeline of variant `v` from its `source` (read from `path`), with these override constants.
fn compile(
    gpu: &Gpu,
    v: &Variant,
    path: &Path,
    source: &str,
    constants: &[(&str, f64)],
) -> Result<wgpu::ComputePipeline> {
    let device = &gpu.device;
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(&v.name),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(&v.name),
        layout: None,
        module: &module,
        entry_point: Some(&v.entry),
        compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
        cache: None,
    });
    if let Some(e) = pollster::block_on(scope.pop()) {
        // wgpu's report spans lines (the cause, naga's diagnostic with the source): one line of it.
        let report = e.to_string();
        let detail: Vec<&str> = report.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
        bail!("{}: entry point {}: {}", path.display(), v.entry, detail.join("; "));
    }
    Ok(pipeline)
}

/// (milliseconds per run, K ranges, max error against float64 on sampled outputs) of one variant on one shape,
/// its pipeline from `pipeline_for` given the shape's params.
fn time_variant(
    gpu: &Gpu,
    v: &Variant,
    (m, k, n): (usize, usize, usize),
    runs: usize,
    pipeline_for: impl Fn(&MatmulParams) -> Result<wgpu::ComputePipeline>,
) -> Result<(f64, usize, f64)> {
    let (device, queue) = (&gpu.device, &gpu.queue);
    let (k4, n4) = (k.div_ceil(4), n.div_ceil(4));
    let mut rng = Rng::new((m * 31 + k * 7 + n) as u64);
    let mut padded = |rows: usize| -> Vec<f32> {
        let mut data = vec![0f32; rows * k4 * 4];
        for row in data.chunks_mut(k4 * 4) {
            row[..k].copy_from_slice(&rng.vec_f32(k, -1.0, 1.0));
        }
        data
    };
    let (x, w) = (padded(m), padded(n));
    // Layer norm's gamma and beta, zero in the padding columns (as the engine's are).
    let (gamma, beta) = (padded(1), padded(1));
    let mut bias = rng.vec_f32(n, -1.0, 1.0);
    bias.resize(n4 * 4, 0.0);
    let m_tiles = m.div_ceil(v.tile.0);
    let tiles = m_tiles * n.div_ceil(v.tile.1);
    let (splits, k_split4) = if v.auto_split { split_k(tiles, k4) } else { (1, k4) };
    let params = MatmulParams {
        m: m as u32,
        n: n as u32,
        k4: k4 as u32,
        n4: n4 as u32,
        act: 0,
        slope: 0.0,
        has_bias: 1,
        accumulate: 0,
        w_ld4: k4 as u32,
        splits: splits as u32,
        k_split4: k_split4 as u32,
        m_tiles: m_tiles as u32,
        norm: u32::from(v.norm),
    };
    // Each row's statistics in `row_stats`'s form: x0, the mean of the deviations from it, 1 / std (taken in
    // float64, so that the check measures the kernel).
    let stats: Vec<f32> = (0..m)
        .flat_map(|i| {
            let r: Vec<f64> = x[i * k4 * 4..][..k].iter().map(|&v| f64::from(v)).collect();
            let delta = r.iter().map(|v| v - r[0]).sum::<f64>() / k as f64;
            let var = r.iter().map(|v| ((v - r[0]) - delta).powi(2)).sum::<f64>() / k as f64;
            [r[0], delta, 1.0 / (var + 1e-5).sqrt(), 0.0].map(|v| v as f32)
        })
        .collect();
    let pipeline = &pipeline_for(&params)?;
    let buffer = |label: &str, contents: &[u8], usage| {
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
    };
    let storage = wgpu::BufferUsages::STORAGE;
    let uniform = buffer("params", bytemuck::cast_slice(&params.words()), wgpu::BufferUsages::UNIFORM);
    let (xb, wb, bb, gb, betab, sb) = (
        buffer("x", bytemuck::cast_slice(&x), storage),
        buffer("w", bytemuck::cast_slice(&w), storage),
        buffer("bias", bytemuck::cast_slice(&bias), storage),
        buffer("gamma", bytemuck::cast_slice(&gamma), storage),
        buffer("beta", bytemuck::cast_slice(&beta), storage),
        buffer("stats", bytemuck::cast_slice(&stats), storage),
    );
    let out_bytes = (splits * m * n4 * 16) as u64;
    let out = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("out"),
        size: out_bytes,
        usage: storage | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let read = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read"),
        size: out_bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bound = [&uniform, &xb, &wb, &bb, &out, &gb, &betab, &sb];
    let entries: Vec<_> = (0..v.bindings)
        .map(|i| wgpu::BindGroupEntry { binding: i, resource: bound[i as usize].as_entire_binding() })
        .collect();
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    });
    let groups = tiles * splits;
    let (gx, gy) = if groups <= 65535 { (groups, 1) } else { (65535, groups.div_ceil(65535)) };
    let dispatch = |count: usize| -> Result<()> {
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            for _ in 0..count {
                pass.dispatch_workgroups(gx as u32, gy as u32, 1);
            }
        }
        queue.submit([encoder.finish()]);
        gpu.wait()?;
        Ok(())
    };
    dispatch(1)?;
    // The fastest of 5 submissions of `runs` back-to-back dispatches (1 on CPU adapters).
    let mut best = f64::MAX;
    for _ in 0..if runs > 1 { 5 } else { 1 } {
        let start = Instant::now();
        dispatch(runs)?;
        best = best.min(start.elapsed().as_secs_f64() / runs as f64);
    }
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(&out, 0, &read, 0, out_bytes);
    queue.submit([encoder.finish()]);
    read.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    gpu.wait()?;
    let got: Vec<f32> =
        bytemuck::cast_slice(&read.slice(..).get_mapped_range().context("reading back the output")?).to_vec();
    // The four corners and 4092 random outputs against float64.
    let mut error = 0f64;
    let corners = [(0, 0), (m - 1, n - 1), (0, n - 1), (m - 1, 0)];
    let sampled: Vec<(usize, usize)> = (4..4096).map(|_| (rng.range(0, m - 1), rng.range(0, n - 1))).collect();
    // Row i of x as the kernel multiplies it: layer-normalised (float64, eps 1e-5) with `norm`.
    let row = |i: usize| -> Vec<f64> {
        let r: Vec<f64> = x[i * k4 * 4..][..k].iter().map(|&v| f64::from(v)).collect();
        if !v.norm {
            return r;
        }
        let mean = r.iter().sum::<f64>() / k as f64;
        let rstd = 1.0 / (r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / k as f64 + 1e-5).sqrt();
        r.iter().enumerate().map(|(c, v)| (v - mean) * rstd * f64::from(gamma[c]) + f64::from(beta[c])).collect()
    };
    for &(i, j) in corners.iter().chain(&sampled) {
        let expected: f64 =
            bias[j] as f64 + row(i).iter().enumerate().map(|(c, r)| r * w[j * k4 * 4 + c] as f64).sum::<f64>();
        let mut sum: f64 = (0..splits).map(|s| got[(s * m + i) * n4 * 4 + j] as f64).sum();
        if splits > 1 && v.name.starts_with("engine") {
            sum += bias[j] as f64;
        }
        error = error.max((sum - expected).abs());
    }
    Ok((best * 1e3, splits, error))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(text: &str) -> Result<Vec<Variant>> {
        let dir = std::env::temp_dir().join(format!("raypatch-gemm-lab-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("manifest.txt"), text).unwrap();
        parse_manifest(&dir.join("manifest.txt"))
    }

    #[test]
    fn manifest_lines_parse_and_bad_ones_name_their_line() {
        let v = manifest(
            "# comment\nengine_tiled engine.wgsl linear_tiled 128 128 8 auto shaped\nrows e.wgsl linear 256 8 5 1\n",
        )
        .unwrap();
        assert_eq!(v.len(), 2);
        assert_eq!((v[0].tile, v[0].bindings, v[0].auto_split, v[0].shaped), ((128, 128), 8, true, true));
        assert_eq!((v[1].entry.as_str(), v[1].auto_split, v[1].shaped), ("linear", false, false));
        for bad in [
            "a b c 0 64 5 1",
            "a b c 64 64 6 1",
            "a b c 64 64 5 2",
            "a b c 64 64 5",
            "a b c 64 64 5 1 fixed",
            "a b c 64 64 5 1 norm",
            "a b c 64 64 7 1",
        ] {
            let e = manifest(&format!("ok f.wgsl main 64 64 5 1\n{bad}\n")).unwrap_err().to_string();
            assert!(e.contains("manifest.txt:2: expected"), "{bad}: {e}");
        }
    }
}
